"""The parameters of the bridge nodes: specs declared as ROS parameters, and the common ones.

``ParameterNode`` is the managed (lifecycle) node that declares its parameters from
``ParameterSpec``s (start-up-only ones read-only, live ones validated and applied when
``ros2 param set`` changes them). ``DeviceDefaults`` and the spec builders
(``transport_specs``, ``unit_id_spec``, ``channel_specs``, ``node_specs``,
``AUTOSTART_SPEC``: the parameters every bridge and bus owner shares, so that the nodes,
the bus owners and the docs agree on them) are plain data, imported from
``bridge_core.runtime.parameters`` only (listed without ROS by
``bridge_core.runtime.interface``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode
from rclpy.parameter import Parameter

from ..runtime.parameters import ParameterSpec, ParameterValue
from ..wire.errors import ConfigurationError
from ..wire.transport import SerialSettings, TcpSettings
from .inbox import Inbox

_KINDS: dict[type, int] = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of a spec: type, range, read-only unless live."""
    text = spec.description
    if spec.choices:
        text += f" ({', '.join(spec.choices)})"
    text += "; live" if spec.live else "; start-up only"
    result = ParameterDescriptor(description=text, read_only=not spec.live)
    if spec.kind in _KINDS:
        result.type = _KINDS[spec.kind]
    if spec.low is not None and spec.high is not None:
        if spec.kind is int:
            result.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high))]
        else:
            result.floating_point_range = [
                FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high))
            ]
    return result


def link_settings(values: dict[str, Any]) -> TcpSettings | SerialSettings:
    """Typed link settings from the transport parameters' values."""
    if "host" in values:
        return TcpSettings(str(values["host"]), int(values["port"]), float(values["timeout_s"]))
    return SerialSettings(
        str(values["serial_port"]),
        int(values["baudrate"]),
        str(values["parity"]).upper(),
        int(values["stopbits"]),
        timeout_s=float(values["timeout_s"]),
        frame_gap_s=float(values["frame_gap_s"]),
    )


class ParameterNode(LifecycleNode):
    """A managed node whose parameters are declared from specs and applied when they
    change. Lifecycle (REP-2002-style, ``rclpy.lifecycle``): ``autostart`` (default true)
    configures and activates it at start, so plain use needs no lifecycle manager."""

    def __init__(self, node_name: str, **node_kwargs: Any) -> None:
        super().__init__(node_name, **node_kwargs)
        change_state = self._service_change_state
        change_state.callback = self._refuse_unavailable_transitions(change_state.callback)
        self._specs: dict[str, ParameterSpec] = {}
        self._appliers: dict[str, list[Callable[[Any], None]]] = {}
        self._writers: dict[str, Callable[[Any], str | None]] = {}
        self.add_pre_set_parameters_callback(self._coerce_parameters)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        # Parts with threads of their own: ended, newest first, before the node is destroyed.
        self.before_destroy: list[Callable[[], None]] = []
        # Command topics that may flood, taken on a thread of their own (inbox.py).
        self.inbox = Inbox(self)
        self.before_destroy.append(self.inbox.close)

    def destroy_node(self) -> None:
        while self.before_destroy:
            self.before_destroy.pop()()
        super().destroy_node()

    def _refuse_unavailable_transitions(
        self, change_state: Callable[[Any, Any], Any]
    ) -> Callable[[Any, Any], Any]:
        """rclpy (7.1) raises out of ``~/change_state`` when asked for a transition the
        current state does not have (transition id 6 while unconfigured), which would end
        the process: answer ``success: false`` instead, as rclcpp does."""

        def guarded(request: Any, response: Any) -> Any:
            try:
                return change_state(request, response)
            except _rclpy.RCLError:
                state = self._state_machine.current_state[1]
                transition = request.transition.label or request.transition.id
                self.get_logger().warning(
                    f"lifecycle: transition {transition} is not available in state {state}"
                )
                response.success = False
                return response

        return guarded

    def declare_specs(self, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
        """Declare parameters; their start-up values by name.

        Raises ``ConfigurationError`` (one line) for a value of the wrong type or range.
        """
        values: dict[str, Any] = {}
        overrides: dict[str, Parameter] = getattr(self, "_parameter_overrides", {})
        for spec in specs:
            self._specs[spec.name] = spec
            value: ParameterValue = spec.default
            ignore_override = False
            if spec.name in overrides:
                given = overrides[spec.name].value
                coerced = spec.coerce(given)
                if coerced is not given:
                    value, ignore_override = coerced, True
            try:
                self.declare_parameter(spec.name, value, descriptor(spec), ignore_override)
            except ParameterException as err:
                given_value = overrides[spec.name].value if spec.name in overrides else None
                raise ConfigurationError(
                    f"{self.get_name()}: parameter {spec.name}: {one_line(err)}"
                    + spec.type_hint(given_value)
                ) from err
            values[spec.name] = self.get_parameter(spec.name).value
        return values

    def on_parameter(self, name: str, apply: Callable[[Any], None]) -> None:
        """Apply a live parameter's new value (after it passed its spec's checks); several
        appliers of one parameter run in the order they were added (``command_timeout_s``
        sets the deadman of a jog guard and of a position guard)."""
        if not self._specs[name].live:
            raise ValueError(f"parameter {name} is start-up only")
        self._appliers.setdefault(name, []).append(apply)

    def on_parameter_write(self, name: str, write: Callable[[Any], str | None]) -> None:
        """A live parameter applied by writing to the device: ``write(value)`` runs while
        the set is checked and returns None once the device took it, or the reason it did
        not (the set is then refused and the parameter keeps its value). Of several
        parameters set at once, the ones written before a refusal stay written."""
        if not self._specs[name].live:
            raise ValueError(f"parameter {name} is start-up only")
        self._writers[name] = write

    def _coerce_parameters(self, parameters: list[Parameter]) -> list[Parameter]:
        out = []
        for parameter in parameters:
            spec = self._specs.get(parameter.name)
            value = parameter.value
            coerced = spec.coerce(value) if spec is not None else value
            out.append(parameter if coerced is value else Parameter(parameter.name, value=coerced))
        return out

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            spec = self._specs.get(parameter.name)
            if spec is None:
                continue
            reason = spec.validate(parameter.value)
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        for parameter in parameters:
            write = self._writers.get(parameter.name)
            if write is not None and (reason := write(parameter.value)) is not None:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            appliers = self._appliers.get(parameter.name, [])
            for apply in appliers:
                apply(parameter.value)
            if appliers:
                self.get_logger().info(f"parameter {parameter.name} set to {parameter.value!r}")


def one_line(err: BaseException) -> str:
    """An error's text on one line (a configuration error is one line on the console)."""
    return " ".join(str(err).split())


__all__ = [
    "ParameterNode",
    "descriptor",
    "link_settings",
    "one_line",
]
