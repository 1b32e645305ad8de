"""Malformed description files as users write them: each variant of ``BASE`` and the
line its fault is on (tests/modbus/test_malformed.py runs them through all three commands).

Each case is (id, old, new, line, words): ``old`` replaced by ``new`` once in ``BASE``
(or ``new`` as the whole file when ``old`` is empty; bytes for binary files), the line
the first problem must name, and words its message must hold.
"""

from __future__ import annotations

# Line numbers below count from 1 in this text.
BASE = """\
device:
  name: pump
  manual: "Pump manual v1"
  link:
    tcp: {host: 127.0.0.1, port: 1502}
    timeout_s: 0.5
  unit_id: 3
  max_read_registers: 60
registers:
  - name: speed
    table: holding
    address: 10
    type: i32
    scale: 10
    unit: rpm
    access: RW
    range: [-3000, 3000]
    manual: "s4.1"
  - {name: angle, table: input, address: 0, type: f32, unit: deg, manual: "s4.2"}
  - {name: run, table: coil, address: 0, type: bool, access: RW, manual: "s5"}
  - {name: mode, table: holding, address: 20, type: u16, access: RW, values: [0, 1, 2], manual: "s6"}
joints:
  - {name: shaft, position: {register: angle}, velocity: {register: speed}}
commands:
  triggers:
    - {name: start, writes: [{register: run, value: true}], starts_motion: true}
    - {name: halt, writes: [{register: run, value: false}], stop: true}
  values:
    - {name: set_mode, register: mode}
"""  # noqa: E501

RTU_LINK = "    tcp: {host: 127.0.0.1, port: 1502}\n"
# The file's last line (30 once a line is appended after it: a keepalive).
LAST = "    - {name: set_mode, register: mode}\n"
# From the mode register's row (line 21) to the end: for cases changing it and the tail.
MODE_TO_END = BASE[BASE.index("  - {name: mode,") :]

Case = tuple[str, str, str | bytes, int, str]

CASES: list[Case] = [
    # --- bytes and YAML syntax
    ("binary_file", "", b"\x7fELF\x02\x01\x01\x00\x00\x00\xff\xfe\n", 1, "not UTF-8"),
    ("latin1_byte", 'manual: "s4.2"', 'manual: "s4.2 \udcb0"', 19, "not UTF-8"),
    ("nul_byte", 'manual: "s5"', 'manual: "s5\x00"', 20, "not allowed in YAML"),
    ("empty_file", "", "", 1, "must be a mapping"),
    ("a_list", "", "- a\n- b\n", 1, "must be a mapping"),
    ("a_scalar", "", "just text\n", 1, "must be a mapping"),
    ("tab_indent", "    table: holding\n", "\ttable: holding\n", 11, "not valid YAML"),
    ("unclosed_flow", 'unit: deg, manual: "s4.2"}', 'unit: deg, manual: "s4.2"', 20, "YAML"),
    ("bad_indent", "    type: i32\n", "     type: i32\n", 13, "not valid YAML"),
    ("two_documents", "", BASE + "---\ndevice: {}\n", 30, "not valid YAML"),
    # a quoted text may span lines: YAML sees the fault where the next quote closes it
    ("unclosed_quote", 'manual: "s4.1"', 'manual: "s4.1', 19, "not valid YAML"),
    # --- tags, keys, aliases
    ("python_tag", "scale: 10", "scale: !!python/object/apply:os.system [ls]", 14, "!!python"),
    ("python_name", "unit: rpm", "unit: !!python/name:os.system ''", 15, "!!python"),
    ("unknown_tag", "unit: rpm", "unit: !degrees rpm", 15, "tag !degrees"),
    ("binary_tag", "unit: rpm", "unit: !!binary aGVsbG8=", 15, "!!binary"),
    ("timestamp_tag", "unit: rpm", "unit: !!timestamp 2001-12-14", 15, "!!timestamp"),
    ("set_tag", "    access: RW\n", "    access: !!set {R, W}\n", 16, "!!set"),
    ("complex_key", "    unit: rpm\n", "    ? [a, b]\n    : rpm\n", 15, "plain name"),
    ("mapping_key", "    unit: rpm\n", "    ? {a: 1}\n    : rpm\n", 15, "plain name"),
    ("recursive_alias", "joints:\n", "loop: &x [1, *x]\njoints:\n", 22, "recursive alias"),
    ("recursive_map", "joints:\n", "loop: &y {a: *y}\njoints:\n", 22, "recursive alias"),
    (
        "billion_laughs",
        "joints:\n",
        "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n"
        + "".join(
            f"{k}: &{k} [{', '.join([f'*{p}'] * 10)}]\n"
            for p, k in zip("abcde", "bcdef", strict=True)
        )
        + "joints:\n",
        27,
        "more than",
    ),
    ("undefined_alias", "scale: 10", "scale: *nothing", 14, "not valid YAML"),
    ("duplicate_key", "    unit: rpm\n", "    unit: rpm\n    unit: rps\n", 16, "given twice"),
    ("merge_not_mapping", "    unit: rpm\n", "    <<: 5\n", 15, "takes a mapping"),
    # --- YAML 1.1 numbers and quoted numbers
    ("octal_address", "address: 10\n", "address: 0100\n", 12, "leading zero"),
    ("octal_scale", "scale: 10", "scale: 010", 14, "leading zero"),
    ("octal_unit_id", "unit_id: 3", "unit_id: 03", 7, "leading zero"),
    ("base60_address", "address: 10\n", "address: 1:30\n", 12, "'1:30' is text"),
    ("underscore_number", "address: 10\n", "address: 1_000\n", 12, "is text"),
    ("quoted_address", "address: 10\n", 'address: "10"\n', 12, "'10' is text"),
    ("quoted_scale", "scale: 10", 'scale: "100"', 14, "'100' is text"),
    ("quoted_unit_id", "unit_id: 3", "unit_id: '3'", 7, "is text"),
    ("quoted_port", "port: 1502", 'port: "1502"', 5, "is text"),
    ("quoted_timeout", "timeout_s: 0.5", 'timeout_s: "0.5"', 6, "is text"),
    ("quoted_range", "range: [-3000, 3000]", 'range: ["-3000", 3000]', 17, "is text"),
    ("quoted_values", "values: [0, 1, 2]", 'values: [0, "1", 2]', 21, "is text"),
    ("float_address", "address: 10\n", "address: 10.5\n", 12, "address"),
    ("bool_address", "address: 10\n", "address: true\n", 12, "address"),
    ("inf_scale", "scale: 10", "scale: .inf", 14, "finite"),
    ("nan_offset", "    unit: rpm\n", "    unit: rpm\n    offset: .nan\n", 16, "finite"),
    ("yes_is_text", "stop: true", "stop: yes", 27, "'yes'"),
    ("hex_too_big", "address: 10\n", "address: 0x10000\n", 12, "65535"),
    ("negative_address", "address: 10\n", "address: -1\n", 12, "greater than or equal"),
    # --- keys: unknown, misspelt, missing
    ("misspelt_address", "    address: 10\n", "    adress: 10\n", 12, "did you mean `address`"),
    ("misspelt_table", "    table: holding\n", "    tabel: holding\n", 11, "did you mean `table`"),
    ("misspelt_unit_id", "unit_id: 3", "unit_idd: 3", 7, "did you mean `unit_id`"),
    ("misspelt_registers", "registers:\n", "register:\n", 9, "did you mean `registers`"),
    ("misspelt_manual", 'manual: "Pump', 'manuel: "Pump', 3, "did you mean `manual`"),
    (
        "misspelt_in_joint",
        "position: {register: angle}",
        "positon: {register: angle}",
        23,
        "mean `position`",
    ),
    ("unknown_key", "    unit: rpm\n", "    unit: rpm\n    colour: red\n", 16, "unknown key"),
    ("missing_type", "    type: i32\n", "", 10, "type: missing"),
    ("missing_manual", '    manual: "s4.1"\n', "", 10, "manual: missing"),
    ("missing_device", "device:\n  name: pump\n", "devic:\n  name: pump\n", 1, "mean `device`"),
    (
        "joints_not_a_list",
        "joints:\n  - {name: shaft, position: {register: angle}, velocity: {register: speed}}\n",
        "joints: 5\n",
        22,
        "list",
    ),
    # --- choices
    (
        "parity_false",
        RTU_LINK,
        "    rtu: {serial_port: /dev/ttyUSB0, parity: false}\n",
        5,
        "quote it",
    ),
    ("parity_word", RTU_LINK, "    rtu: {serial_port: /dev/ttyUSB0, parity: no}\n", 5, "'no'"),
    ("stopbits_3", RTU_LINK, "    rtu: {serial_port: /dev/ttyUSB0, stopbits: 3}\n", 5, "stopbits"),
    ("bad_table", "table: holding\n", "table: holdings\n", 11, "holding"),
    ("bad_type", "type: i32\n", "type: int32\n", 13, "'i32'"),
    ("bad_access", "access: RW\n", "access: rw\n", 16, "'RW'"),
    # --- checks that need several keys
    (
        "unit_id_0_rtu",
        RTU_LINK + "    timeout_s: 0.5\n  unit_id: 3",
        "    rtu: {serial_port: /dev/ttyUSB0}\n    timeout_s: 0.5\n  unit_id: 0",
        7,
        "broadcast",
    ),
    ("unit_id_248", "unit_id: 3", "unit_id: 248", 7, "247"),
    (
        "coil_as_u16",
        "table: coil, address: 0, type: bool",
        "table: coil, address: 0, type: u16",
        20,
        "coil",
    ),
    ("overlap", "address: 20, type: u16", "address: 11, type: u16", 21, "overlaps"),
    ("range_reversed", "range: [-3000, 3000]", "range: [3000, -3000]", 17, "minimum > maximum"),
    ("unknown_joint_register", "{register: angle}", "{register: angel}", 23, "no register named"),
    (
        "trigger_unknown_register",
        "{register: run, value: true}",
        "{register: runn, value: true}",
        26,
        "no register",
    ),
    (
        "trigger_value_type",
        "{register: run, value: true}",
        "{register: run, value: 5}",
        26,
        "true or false",
    ),
    ("value_not_allowed", "register: mode}", "register: angle}", 29, "read only"),
    ("reserved_name", "name: set_mode", "name: read", 29, "reserved"),
    ("duplicate_name", "name: angle, table", "name: speed, table", 19, "defined twice"),
    (
        "too_many_registers",
        "max_read_registers: 60",
        "max_read_registers: 1",
        13,
        "more than one read",
    ),
    (
        "no_link",
        "  link:\n" + "    tcp: {host: 127.0.0.1, port: 1502}\n    timeout_s: 0.5\n",
        "",
        1,
        "link",
    ),
    # --- round 3: keepalive, starts_motion, link and poll keys
    (
        "keepalive_value_not_allowed",  # item 1: a feed ~/write would refuse
        LAST,
        LAST + "keepalive: {register: mode, value: 5, period_s: 1.0}\n",
        30,
        "mode takes one of 0, 1, 2, not 5",
    ),
    (
        "keepalive_value_not_whole",  # item 1
        LAST,
        LAST + "keepalive: {register: mode, value: 1.5, period_s: 1.0}\n",
        30,
        "takes a whole number",
    ),
    (
        "trigger_without_starts_motion",  # item 2
        "value: true}], starts_motion: true}",
        "value: true}]}",
        26,
        "does not say whether it starts motion",
    ),
    (
        "service_on_a_stop_register",  # item 2: a coil service writing what a stop writes
        LAST,
        LAST + "  coils:\n    - {name: set_run, register: run}\n",
        31,
        "say starts_motion: false",
    ),
    (
        "keepalive_write_only_without_value",  # item 3
        MODE_TO_END,
        MODE_TO_END.replace("access: RW, values", "access: W, values")
        + "keepalive: {register: mode, period_s: 1.0}\n",
        30,
        "write-only",
    ),
    (
        "keepalive_any_frame_polls_too_slow",  # item 4: the polls are the feeds
        LAST,
        LAST + "keepalive: {mode: any_frame, period_s: 0.2}\n",
        30,
        "poll_rate_hz >= 15",
    ),
    (
        "keepalive_any_frame_with_register",  # item 4
        LAST,
        LAST + "keepalive: {mode: any_frame, register: mode, period_s: 1.0}\n",
        30,
        "feeds no register",
    ),
    (
        "baudrate_19201",
        RTU_LINK,
        "    rtu: {serial_port: /dev/ttyUSB0, baudrate: 19201}\n",
        5,
        "19200",
    ),
    (
        "parity_x",
        RTU_LINK,
        "    rtu: {serial_port: /dev/ttyUSB0, parity: X}\n",
        5,
        "none, even, odd",
    ),
    (
        "run_value_not_allowed",  # item 9: a run value the run register never takes
        "velocity: {register: speed}}",
        "velocity: {register: speed}, sim: {command: speed, run_register: mode, run_values: [7]}}",
        23,
        "mode takes one of 0, 1, 2, not 7",
    ),
    (
        "device_poll_default_bad",  # item 9: the file's default poll group
        "  max_read_registers: 60\n",
        "  max_read_registers: 60\n  poll: sometimes\n",
        9,
        "'slow'",
    ),
]
