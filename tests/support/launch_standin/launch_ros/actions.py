"""Stand-ins of ``launch_ros.actions``: a node's arguments, recorded."""

from __future__ import annotations

from typing import Any


class Node:
    lifecycle = False

    def __init__(
        self,
        *,
        package: Any,
        executable: Any,
        name: Any = None,
        namespace: Any = "",
        parameters: list[Any] | None = None,
        arguments: list[Any] | None = None,
        **kwargs: Any,
    ) -> None:
        self.package = package
        self.executable = executable
        self.name = name
        self.namespace = namespace
        self.parameters = list(parameters or [])
        self.arguments = list(arguments or [])
        self.kwargs = kwargs


class LifecycleNode(Node):
    """launch_ros's LifecycleNode needs ``name`` and ``namespace`` (Jazzy)."""

    lifecycle = True

    def __init__(self, *, name: Any, namespace: Any, **kwargs: Any) -> None:
        super().__init__(name=name, namespace=namespace, **kwargs)
