"""Services and actions come from their interface rows: a row without a handler, or a
handler without a row, stops the node at start-up (``node_services.bound_rows``)."""

from __future__ import annotations

import pytest

from bridge_core.ros.node_services import bound_rows
from bridge_core.runtime.interface import Service
from bridge_core.wire.errors import ConfigurationError

ROWS = (
    Service("~/stop", "std_srvs/srv/Trigger"),
    Service("~/motor_{motor}/move_by", "msg_defs/srv/MoveBy"),
)


def test_each_name_of_a_pattern_gets_its_handler_with_the_placeholder() -> None:
    bound = bound_rows(
        ROWS,
        {"~/stop": "stop", "~/motor_{motor}/move_by": lambda motor: motor * 10},
        {"motor": (1, 2)},
    )
    assert [(name, made) for _, name, made in bound] == [
        ("~/stop", "stop"),
        ("~/motor_1/move_by", 10),
        ("~/motor_2/move_by", 20),
    ]


def test_a_row_without_a_handler_is_refused() -> None:
    with pytest.raises(ConfigurationError, match=r"no handler for ~/motor_\{motor\}/move_by"):
        bound_rows(ROWS, {"~/stop": "stop"}, {"motor": (1,)})


def test_a_handler_without_a_row_is_refused() -> None:
    handlers = {"~/stop": "stop", "~/motor_{motor}/move_by": int, "~/reset": "reset"}
    with pytest.raises(ConfigurationError, match="no row for ~/reset"):
        bound_rows(ROWS, handlers, {"motor": (1,)})
