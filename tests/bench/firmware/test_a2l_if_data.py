"""The A2L's IF_DATA XCP read by a parser that knows XCP's AML: pya2ldb's IF_DATA parser (`pya2l.aml.ifdata_parser`)
with the XCP AML pya2ldb ships (`pya2l/examples/vector.aml`, Vector's rendering of ASAM's XCP 1.x AML, in place
of the A2L's own A2ML block), so the keywords, their order and their enumerations are checked by a grammar that is
not ours; and by the A2L's own A2ML, which must read the IF_DATA into the same values. pya2ldb does not
range-check values (a TIME_CYCLE of 500 in the AML's uchar passed), so the parsed values
are checked here against the AML's types and against what the slave answers."""

from __future__ import annotations

import logging
from importlib.resources import files

import pytest

from bench.firmware.a2l import a2l_text, event_cycle
from bench.model.default import default_artifact_path
from dbc.database import heartbeat_period_s
from dbc.transport import NOMINAL_BITRATE
from dbc.xcp import cmd_id, res_id
from target_sim.artifact import load_artifact
from target_sim.node import TargetNode
from target_sim.xcp.daq import EVENTS

pya2l = pytest.importorskip("pya2l")
ifdata_parser = pytest.importorskip("pya2l.aml.ifdata_parser")
pytest.importorskip("pyxcp.types")

UCHAR, UINT, ULONG = 0xFF, 0xFFFF, 0xFFFFFFFF
# the XCP AML's types of the values we write (vector.aml: struct Protocol_Layer, Daq, its EVENT, CAN_Parameters)
PROTOCOL_LAYER_TYPES = [UINT] * 8 + [UCHAR, UINT]          # version, T1..T7, MAX_CTO, MAX_DTO
DAQ_TYPES = {1: UINT, 2: UINT, 3: UCHAR, 8: UCHAR}          # MAX_DAQ, MAX_EVENT_CHANNEL, MIN_DAQ, MAX_ODT_ENTRY_SIZE
EVENT_TYPES = {2: UINT, 4: UCHAR, 5: UCHAR, 6: UCHAR, 7: UCHAR}   # number, MAX_DAQ_LIST, cycle, unit, priority
CAN_TYPES = {"CAN_ID_MASTER": ULONG, "CAN_ID_SLAVE": ULONG, "BAUDRATE": ULONG}


def xcp_aml() -> str:
    aml = files("pya2l") / "examples" / "vector.aml"
    if not aml.is_file():
        pytest.skip("this pya2ldb ships no XCP AML (examples/vector.aml)")
    return aml.read_text(encoding="latin-1")


def with_vector_aml(a2l: str) -> str:
    """The A2L with XCP's AML as pya2ldb ships it in place of the A2L's own A2ML block."""
    start, end = a2l.index("    /begin A2ML"), a2l.index("    /end A2ML\n") + len("    /end A2ML\n")
    return a2l[:start] + xcp_aml() + "\n" + a2l[end:]


def parsed_if_data(a2l: str, tmp_path, caplog) -> tuple[dict, list[str]]:
    """(what pya2ldb's IF_DATA parser reads from the A2L's one IF_DATA XCP with the A2L's A2ML, what it complained
    of)."""
    from pya2l import model

    path = tmp_path / "with_aml.a2l"
    path.write_text(a2l, encoding="latin-1")
    session = pya2l.import_a2l(str(path), in_memory=True, remove_existing=True, progress_bar=False,
                               loglevel="ERROR")
    blocks = [block.raw for block in session.query(model.IfData).all()]
    assert len(blocks) == 1 and blocks[0].startswith("/begin IF_DATA XCP"), blocks
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pya2l"):
        parsed = ifdata_parser.IfDataParser(session, loglevel="WARNING").parse(blocks[0])
    return parsed, [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]


# what XCP 1.x requires of every slave, of one with CAL/PAG (DOWNLOAD) and of one with DAQ: not OPTIONAL_CMD
MANDATORY = {"CONNECT", "DISCONNECT", "GET_STATUS", "SYNCH", "DOWNLOAD", "CLEAR_DAQ_LIST", "SET_DAQ_PTR",
             "WRITE_DAQ", "SET_DAQ_LIST_MODE", "GET_DAQ_LIST_MODE", "START_STOP_DAQ_LIST", "START_STOP_SYNCH"}


def answered_optional_commands(node: TargetNode) -> list[str]:
    """The optional commands (pyxcp's `Command` names) a connected slave answers with anything but ERR_CMD_UNKNOWN."""
    from pyxcp.types import Command

    answered = []
    for command in Command:
        if command.value > 0xFF or command.name in MANDATORY:     # two-byte codes: the 0xC0 level-1 commands
            continue
        node.xcp.command(bytes((0xFF, 0)))
        reply = node.xcp.command(bytes((command.value,)) + bytes(7))
        if reply is not None and reply[:2] != b"\xfe\x20":
            answered.append(command.name)
    return sorted(answered)


def if_data_problems(parsed: dict, complaints: list[str], node: TargetNode, dt: float) -> list[str]:
    """What is wrong with a parsed IF_DATA XCP: the parser's complaints, a structure not XCP's, a value outside its
    AML type, a value the slave does not answer with."""
    try:
        return complaints + _value_problems(parsed, node, dt)
    except (ValueError, TypeError, IndexError, KeyError, AttributeError) as exc:   # a part missing or misshapen
        return [*complaints, f"structure: {exc!r}"]


def _value_problems(parsed: dict, node: TargetNode, dt: float) -> list[str]:
    problems: list[str] = []
    sections = {name: value for part in parsed.get("XCP", []) for name, value in part.items()}
    if set(sections) != {"PROTOCOL_LAYER", "DAQ", "XCP_ON_CAN"}:
        return [f"sections {sorted(sections)}"]
    *layer, byte_order, granularity, commands = sections["PROTOCOL_LAYER"]
    problems += [f"PROTOCOL_LAYER[{i}] {v!r}" for i, (v, top) in enumerate(zip(layer, PROTOCOL_LAYER_TYPES,
                                                                             strict=True))
                 if not isinstance(v, int) or not 0 <= v <= top]
    connect = node.xcp.command(bytes((0xFF, 0)))     # MAX_CTO, MAX_DTO and the byte order as CONNECT answers
    if (layer[0], layer[8], layer[9]) != (0x0100, connect[3], int.from_bytes(connect[4:6], "little")):
        problems.append(f"version, MAX_CTO, MAX_DTO {layer[0], layer[8], layer[9]} vs CONNECT {connect.hex()}")
    if (byte_order, granularity) != ("BYTE_ORDER_MSB_LAST", "ADDRESS_GRANULARITY_BYTE") or connect[2] & 0x07:
        problems.append(f"byte order {byte_order}, {granularity}")
    optional = answered_optional_commands(TargetNode(node.artifact))
    if sorted(commands.get("OPTIONAL_CMD", [])) != optional:
        problems.append(f"OPTIONAL_CMD {commands.get('OPTIONAL_CMD')}, the slave answers {optional}")
    *daq, events = sections["DAQ"]
    problems += [f"DAQ[{i}] {daq[i]!r}" for i, top in DAQ_TYPES.items()
                 if not isinstance(daq[i], int) or not 0 <= daq[i] <= top]
    info = node.xcp.command(bytes((0xDA,)))                       # GET_DAQ_PROCESSOR_INFO
    if daq[0] != "DYNAMIC" or (daq[1], daq[2]) != (int.from_bytes(info[2:4], "little"),
                                                   int.from_bytes(info[4:6], "little")):
        problems.append(f"DAQ {daq[:3]} vs GET_DAQ_PROCESSOR_INFO {info.hex()}")
    periods = {0: dt * 1000, 1: heartbeat_period_s() * 1000}
    for event in events.get("EVENT", []):
        problems += [f"EVENT {event[0]} [{i}] {event[i]!r}" for i, top in EVENT_TYPES.items()
                     if not isinstance(event[i], int) or not 0 <= event[i] <= top]
        if len(event[1]) > 8 or EVENTS.get(event[2]) != event[0] or event[3] != "DAQ":
            problems.append(f"EVENT {event}")
        elif event[5] * 10 ** (event[6] - 6) != pytest.approx(periods[event[2]], rel=0.05):
            problems.append(f"EVENT {event[0]} every {event[5]} x unit {event[6]}, not {periods[event[2]]} ms")
    if sorted(e[2] for e in events.get("EVENT", [])) != sorted(EVENTS):
        problems.append(f"events {events}")
    (can_version, can), = sections["XCP_ON_CAN"]
    if can_version != 0x0100 or can != {"CAN_ID_MASTER": cmd_id(), "CAN_ID_SLAVE": res_id(),
                                        "BAUDRATE": NOMINAL_BITRATE}:
        problems.append(f"XCP_ON_CAN {can_version} {can}")
    problems += [f"{k} {v!r}" for k, v in can.items() if not isinstance(v, int) or not 0 <= v <= CAN_TYPES[k]]
    return problems


@pytest.fixture(scope="module")
def artifact():
    return load_artifact(default_artifact_path())


def test_the_if_data_parses_with_xcps_aml_and_holds_what_the_slave_answers(artifact, tmp_path, caplog):
    parsed, complaints = parsed_if_data(with_vector_aml(a2l_text(artifact)), tmp_path, caplog)
    assert if_data_problems(parsed, complaints, TargetNode(artifact), artifact.dt) == []


def test_the_a2ls_own_a2ml_reads_its_if_data_as_xcps_aml_does(artifact, tmp_path, caplog):
    """The A2L's own A2ML block (no AML added): pya2ldb parses it, and its IF_DATA parser reads the IF_DATA by it
    without a complaint into what it reads by the XCP AML pya2ldb ships."""
    text = a2l_text(artifact)
    assert text.count("/begin A2ML") == 1
    own, complaints = parsed_if_data(text, tmp_path, caplog)
    assert complaints == [] and own == parsed_if_data(with_vector_aml(text), tmp_path, caplog)[0]
    assert if_data_problems(own, complaints, TargetNode(artifact), artifact.dt) == []


@pytest.mark.parametrize(("written", "edited"), [
    ("CAN_ID_MASTER", "CAN_ID_MASTR"),                       # a keyword XCP's AML does not have
    ("BYTE_ORDER_MSB_LAST", "BYTE_ORDER_LSB_FIRST"),         # an enumeration value it does not have
    ("OPTIONAL_CMD GET_ID", "OPTIONAL_CMD GET_IDENTIFIER"),
    ("DAQ 255 50 7 0", "DAQ 255 500 6 0"),                   # the model step's 500 ms in 1 ms: no uchar
    ("BAUDRATE 500000", "BAUDRATE 250000"),                  # not the bus's bit rate
])
def test_a_wrong_if_data_is_found(artifact, tmp_path, caplog, written, edited):
    """The check fails on what it is there to catch: each of these edits of the IF_DATA is reported."""
    text = a2l_text(artifact)
    assert written in text
    for a2l in (text, with_vector_aml(text)):       # by its own A2ML, and by XCP's AML
        parsed, complaints = parsed_if_data(a2l.replace(written, edited, 1), tmp_path, caplog)
        assert if_data_problems(parsed, complaints, TargetNode(artifact), artifact.dt) != []


def test_an_event_cycle_fits_the_amls_uchar():
    assert event_cycle(100) == (100, 6) and event_cycle(500) == (50, 7) and event_cycle(2000) == (200, 7)
    assert event_cycle(60_000) == (60, 9)
