"""``bridge_doc BRIDGE``: prints, writes or checks the ROS API reference of a bridge's page
(``docs/bridges/<bridge>.md``), rendered by ``bridge_core.runtime.interface_doc`` from its
``<bridge>/interface.py``.

``bridge_doc --write`` rewrites the generated section, ``bridge_doc --check`` fails when a
page differs from a fresh render (tests/core/ros/test_bridge_doc.py runs the same
comparison). ROS-free, as ``bridge_plot``: the listing needs no rclpy.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..runtime import entries
from ..runtime.interface import Bridge, bridges
from ..runtime.interface_doc import PageError, new_page, region, render, split_page

PAGES = Path("docs") / "bridges"  # under the repository root
EXIT_DIFFERS = 1  # --check: a page is not what bridge_doc renders
EXIT_USAGE = 2  # a bad name, a page the tool cannot rewrite


def page_name(bridge: Bridge) -> str:
    """The page as messages name it: relative to the repository root."""
    return str(PAGES / f"{bridge.name}.md")


def page(bridge: Bridge, root: Path) -> Path:
    return root / page_name(bridge)


def written(bridge: Bridge, root: Path) -> str:
    """The page's text with a fresh section (a new page if there is none)."""
    path = page(bridge, root)
    rendered = render(bridge)
    if not path.exists():
        return new_page(bridge, rendered)
    before, _, after = split_page(path.read_text(encoding="utf-8"), page_name(bridge))
    return before + rendered + after


def differs(bridge: Bridge, root: Path) -> str | None:
    """Why the page is not what bridge_doc renders (one line), or None."""
    path = page(bridge, root)
    fix = f"run `bridge_doc --write {bridge.name}`"
    if not path.exists():
        return f"{page_name(bridge)}: missing; {fix}"
    try:
        current = region(path.read_text(encoding="utf-8"), page_name(bridge))
    except PageError as err:
        return str(err)
    if current != render(bridge):
        return f"{page_name(bridge)}: differs from `bridge_doc {bridge.name}`; {fix}"
    return None


def chosen(names: Sequence[str], known: Mapping[str, Bridge]) -> list[Bridge]:
    unknown = [name for name in names if name not in known]
    if unknown:
        raise PageError(f"unknown bridge {unknown[0]!r} (one of {', '.join(known)})")
    return [known[name] for name in names or known]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bridge_doc", description="a bridge's ROS API reference, from its interface.py"
    )
    parser.add_argument(
        "bridges", nargs="*", metavar="BRIDGE", help="r6, xarm, ... (--write, --check: default all)"
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="rewrite docs/bridges/BRIDGE.md")
    mode.add_argument("--check", action="store_true", help="exit 1 if a page differs")
    parser.add_argument("--root", type=Path, default=entries.ROOT, help="repository root")
    args = parser.parse_args(argv)
    try:
        targets = chosen(args.bridges, bridges())
        if args.check:
            found = [line for b in targets if (line := differs(b, args.root)) is not None]
            for line in found:
                print(line)
            return EXIT_DIFFERS if found else 0
        if args.write:
            texts = {page(b, args.root): written(b, args.root) for b in targets}  # all or none
            for path, text in texts.items():
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(text, encoding="utf-8")
            return 0
        if len(args.bridges) != 1:
            raise PageError("name one bridge to print (or give --write or --check)")
        sys.stdout.write(render(targets[0]))
        return 0
    except (PageError, OSError) as err:  # one line for the user, not a traceback
        print(f"bridge_doc: {err}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
