"""Branches decided by globals a mode fixes (target_sim.firmware.known_values), on Thumb-2 code as clang writes it for
bench/firmware/xcp.c's tests of xcp_connected and daq_lists: decided when the block plainly loads the global and
tests it, undecided as soon as anything in between could change what it tests."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from target_sim.firmware.cycles import new_disassembler
from target_sim.firmware.elf import Symbol
from target_sim.firmware.known_values import ValueFactError, decided_branch, memory_reader
from target_sim.firmware.wcet import value_facts

FLAG, COUNT = 0x2000_0050, 0x2000_05BC          # a uint8_t and a uint32_t global
IMAGE = SimpleNamespace(name="test.elf", symbols={"flag": Symbol("flag", FLAG, 1, "STT_OBJECT", False),
                                                  "count": Symbol("count", COUNT, 4, "STT_OBJECT", False)})
LOAD_FLAG = "40f25001" "c2f20001" "0978"        # movw r1, #0x50; movt r1, #0x2000; ldrb r1, [r1]
TEST_FLAG = "0129" "40f04081"                   # cmp r1, #1; bne.w (away)
LOAD_COUNT = "40f2bc51" "c2f20001" "0a68"       # movw r1, #0x5bc; movt r1, #0x2000; ldr r2, [r1]
RETURN_IF_ZERO = "002a" "08bf" "7047"           # cmp r2, #0; it eq; bxeq lr
CALL = "00f000f8"                               # bl (the next instruction)


def block(hexcode: str) -> list:
    return list(new_disassembler().disasm(bytes.fromhex(hexcode), 0x0800_0000))


@pytest.mark.parametrize(("flag", "taken"), [(0, True), (1, False), (7, True)])
def test_a_load_and_compare_of_a_known_global_decides_the_branch(flag, taken):
    read = memory_reader(IMAGE, {"flag": flag})
    assert decided_branch(block(LOAD_FLAG + TEST_FLAG), read) is taken


def test_a_conditional_return_in_an_it_block_and_cbz_are_decided():
    assert decided_branch(block(LOAD_COUNT + RETURN_IF_ZERO), memory_reader(IMAGE, {"count": 0})) is True
    assert decided_branch(block(LOAD_COUNT + RETURN_IF_ZERO), memory_reader(IMAGE, {"count": 3})) is False
    assert decided_branch(block(LOAD_COUNT + "0ab1"), memory_reader(IMAGE, {"count": 0})) is True     # cbz r2
    assert decided_branch(block(LOAD_COUNT + "0ab9"), memory_reader(IMAGE, {"count": 0})) is False    # cbnz r2


def test_nothing_is_decided_without_the_value_or_across_what_could_change_it():
    known = memory_reader(IMAGE, {"flag": 0})
    assert decided_branch(block(LOAD_FLAG + TEST_FLAG), memory_reader(IMAGE, {"count": 0})) is None   # not known
    assert decided_branch(block(LOAD_FLAG + CALL + TEST_FLAG), known) is None        # a call clobbers r1
    assert decided_branch(block(LOAD_FLAG + "0131" + TEST_FLAG), known) is None      # adds r1, #1: r1 unknown
    assert decided_branch(block(LOAD_FLAG + "0129" + "0131" + "40f04081"), known) is None   # adds sets the flags
    assert decided_branch(block(LOAD_COUNT + "0ab1"), known) is None                 # count is not fixed
    assert decided_branch(block("c2f20001" "0978" + TEST_FLAG), known) is None       # movt alone: no address


def test_a_load_straddling_a_known_global_is_unknown_and_bad_facts_are_refused():
    read = memory_reader(IMAGE, {"count": 0x0403_0201})
    assert (read(COUNT, 4), read(COUNT + 1, 1), read(COUNT + 2, 2), read(COUNT + 2, 4)) == (0x0403_0201, 2, 0x0403,
                                                                                             None)
    with pytest.raises(ValueFactError, match="no global 'missing'"):
        memory_reader(IMAGE, {"missing": 0})
    with pytest.raises(ValueFactError, match="does not fit its 1 bytes"):
        memory_reader(IMAGE, {"flag": 256})


def test_value_facts_are_read_per_mode_from_the_c_and_a_malformed_one_is_refused():
    sources = {"a.c": "static uint8_t a, b;   /* wcet-value(quiet): a = 0, b = 3 */\n"
                      "static uint32_t c;     /* wcet-value(loud): c = 7 */\n"}
    assert value_facts(sources, "quiet") == {"a": 0, "b": 3} and value_facts(sources, "loud") == {"c": 7}
    assert value_facts(sources, "other") == {}
    with pytest.raises(ValueError, match=r"a\.c:1: a wcet-value fact is 'name = N, \.\.\.'"):
        value_facts({"a.c": "int a; /* wcet-value(quiet): a is 0 */"}, "quiet")
