"""The tables of kinds (`target_sim.kinds`, `target_sim.losses`, `bench.motor.losskinds`) name the same kinds as
the DBC's value tables and as each other, and an unknown name is one sentence naming the known ones."""

from __future__ import annotations

import pytest

from dbc.contract import ModelKind, Realization
from target_sim.kinds import MODEL_KINDS, REALIZATIONS, is_delta
from target_sim.registry import Registry, UnknownKind


def test_model_kinds_and_realizations_are_the_dbc_value_tables():
    assert set(MODEL_KINDS.names()) == {kind.label for kind in ModelKind}
    assert set(REALIZATIONS.names()) == {realization.label for realization in Realization}


def test_the_lab_and_the_target_know_the_same_loss_models():
    from bench.motor.losskinds import LAB_LOSS_KINDS
    from target_sim.losses import LOSS_KINDS

    assert LAB_LOSS_KINDS.names() == LOSS_KINDS.names()


def test_every_realization_has_a_builder():
    from bench.thermal.discretize import discretize
    from bench.thermal.lptn import lti_matrices
    from bench.thermal.parameters import TABLE1
    from bench.thermal.realizations import REALIZATIONS as BUILT
    from bench.thermal.realizations import physical, realize

    a, b, c, d = lti_matrices(TABLE1)
    sys = physical(*discretize(a, b, 0.5, "zoh"), c, d)
    assert BUILT == REALIZATIONS.names()
    for name in BUILT:
        assert realize(sys, name, 0.5).a.shape == (4, 4)


def test_what_a_kind_has():
    assert MODEL_KINDS["hammerstein"].input_nonlinearity and MODEL_KINDS["hammerstein"].linear_block
    assert not MODEL_KINDS["pv-lptn"].linear_block and not MODEL_KINDS["pv-lptn"].realizations
    assert is_delta("lti-lptn", "delta") and not is_delta("pv-lptn", "delta") and not is_delta("lti-lptn", "modal")


def test_an_unknown_name_is_one_sentence():
    with pytest.raises(UnknownKind, match=r"^model kind 'lstm' is not one of lti-lptn, pv-lptn, hammerstein$"):
        MODEL_KINDS["lstm"]
    assert issubclass(UnknownKind, ValueError) and issubclass(UnknownKind, LookupError)


def test_a_registry_lists_its_first_kinds_first():
    table: Registry[int] = Registry("thing", first=("b", "a"))
    for name, value in (("c", 3), ("a", 1), ("b", 2)):
        table.register(name, value)
    assert table.names() == ("b", "a", "c") and list(table) == ["b", "a", "c"]
    table.unregister("c")
    assert "c" not in table and table.items() == [("b", 2), ("a", 1)]
