"""Stand-ins of ``launch_ros.substitutions``."""

from __future__ import annotations


class ExecutableInPackage:
    def __init__(self, *, executable: str, package: str) -> None:
        self.executable = executable
        self.package = package
