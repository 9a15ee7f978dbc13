"""A loss model defined here, in the test, and registered on both sides of the layer line (`target_sim.losses`,
`bench.motor.losskinds`), goes the whole way: motor file -> identification -> artifact -> the Python float32
target -> generated C -> the emulated Cortex-M4F, bit for bit. Nothing else in the tree names it: the seams are
the registries.

The kind: losses quadratic in torque and speed (f = n / n_ref): p_dc0 = k_cu·T², p_ac0 = p_dc0·(k_ac·f²),
p_stator = k_fe·f², p_magnet = k_m·f², current = k_i·T²."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np
import pytest

from bench.motor.losskinds import LAB_LOSS_KINDS, LabLossKind
from target_sim.losses import LOSS_KINDS, LossKind

NAME = "quadratic-test"
KEYS = ("qt_speed_ref", "qt_copper", "qt_ac", "qt_iron", "qt_magnet", "qt_current")


class QuadraticEvaluator:
    def __init__(self, artifact, dtype=np.float32):
        self.f = f = np.dtype(dtype).type
        self.c = {k: artifact.array("losses", k, dtype=f)[()] for k in KEYS}

    def lookup(self, torque, speed) -> np.ndarray:
        c, f = self.c, self.f
        ratio = f(speed) / c["qt_speed_ref"]
        t2 = f(torque) * f(torque)
        f2 = ratio * ratio
        p_dc0 = c["qt_copper"] * t2
        return np.array([p_dc0, p_dc0 * (c["qt_ac"] * f2), c["qt_iron"] * f2, c["qt_magnet"] * f2,
                         c["qt_current"] * t2], dtype=f)


class QuadraticTarget(LossKind):
    name = NAME
    inputs = ("torque_Nm", "speed_rpm")
    summary = "losses quadratic in torque and speed (a test's kind)"
    c_function = "quadratic_losses"
    c_words = "quadratic loss model"
    c_code = """\
/* QuadraticEvaluator.lookup */
static void quadratic_losses(float torque, float speed, float out[LOSS_TABLE_COUNT])
{
    const float ratio = speed / QT_SPEED_REF;
    const float t2 = torque * torque;
    const float f2 = ratio * ratio;
    const float p_dc0 = QT_COPPER * t2;
    out[0] = p_dc0;
    out[1] = p_dc0 * (QT_AC * f2);
    out[2] = QT_IRON * f2;
    out[3] = QT_MAGNET * f2;
    out[4] = QT_CURRENT * t2;
}
"""

    def fields(self, losses) -> list[tuple[str, ...]]:
        return [(k,) for k in KEYS]

    def evaluator(self, artifact, dtype=np.float32) -> QuadraticEvaluator:
        return QuadraticEvaluator(artifact, dtype)

    def c_scalars(self, artifact):
        return [(k.upper(), ("losses", k), f"losses.{k}") for k in KEYS]

    def ops(self, op: Callable[..., Counter]) -> Counter:
        return op(divide=1, multiply=8, load_store=len(KEYS) + 2 + 5, call=1)

    def coefficient_count(self, artifact) -> int:
        return len(KEYS)


@dataclass(frozen=True)
class QuadraticLosses:
    qt_speed_ref: float
    qt_copper: float
    qt_ac: float
    qt_iron: float
    qt_magnet: float
    qt_current: float

    kind = NAME
    inputs = QuadraticTarget.inputs

    def evaluate_columns(self, columns) -> dict[str, np.ndarray]:
        t = np.asarray(columns["torque_Nm"], dtype=float)
        f2 = (np.asarray(columns["speed_rpm"], dtype=float) / self.qt_speed_ref) ** 2
        p_dc0 = self.qt_copper * t * t
        return {"p_dc0": p_dc0, "p_ac0": p_dc0 * self.qt_ac * f2, "p_stator": self.qt_iron * f2,
                "p_magnet": self.qt_magnet * f2, "current": self.qt_current * t * t}


class QuadraticLab(LabLossKind):
    name = NAME
    keys = KEYS
    summary = QuadraticTarget.summary
    robustness_groups = {"qt_copper": (("qt_copper",),), "qt_iron_magnet": (("qt_iron",), ("qt_magnet",))}

    def from_motor_file(self, check, losses, *, motor_path, pole_pairs, current_max_A):
        return QuadraticLosses(**{k: check.number(losses, f"losses.{k}", positive=True) for k in KEYS}), None

    def artifact_section(self, model, encode):
        return {f.name: encode(getattr(model, f.name)) for f in fields(model)}

    def from_artifact(self, artifact, current_max_A):
        return QuadraticLosses(**{k: float(artifact.array("losses", k, dtype=np.float64)) for k in KEYS})


@pytest.fixture
def quadratic_kind():
    LOSS_KINDS.register(NAME, QuadraticTarget())
    LAB_LOSS_KINDS.register(NAME, QuadraticLab())
    yield NAME
    LOSS_KINDS.unregister(NAME)
    LAB_LOSS_KINDS.unregister(NAME)


def motor_file(kind: str) -> dict:
    """A motor whose losses are roughly the virtual 200 kW motor's at its operating points."""
    return {"name": "quadratic-motor", "pole_pairs": 4,
            "limits": {"torque_Nm": 450.0, "speed_rpm": 12000.0, "current_A": 600.0},
            "losses": {"kind": kind, "copper_reference_C": 20.0, "copper_alpha_per_K": 0.0039,
                       "qt_speed_ref": 6000.0, "qt_copper": 0.02, "qt_ac": 0.3, "qt_iron": 900.0,
                       "qt_magnet": 150.0, "qt_current": 0.004},
            "thermal_prior": {"parameters": "table1", "bounds": [0.6, 1.6]}}


def test_both_tables_name_the_same_kinds():
    assert LOSS_KINDS.names() == LAB_LOSS_KINDS.names() == ("maps", "electrical")


def test_an_unknown_kind_is_one_sentence(tmp_path):
    from bench.motor.description import motor_from_dict
    from bench.motor.errors import MotorFileError

    with pytest.raises(MotorFileError, match="losses.kind must be one of maps, electrical, not 'quadratic-test'"):
        motor_from_dict(motor_file(NAME))


def test_a_robustness_study_perturbs_a_kind_defined_in_a_test_by_its_own_groups(quadratic_kind):
    """bench.robustness reads the kind's `robustness_groups`: no edit there for a new loss kind."""
    import json

    from bench.model.default import default_artifact_path
    from bench.robustness.kinds import PERTURBATIONS
    from target_sim.artifact import encode_array, seal, verify

    content = json.loads(default_artifact_path().read_text(encoding="utf-8"))
    coefficients = {k: v for k, v in motor_file(NAME)["losses"].items() if k in KEYS}
    content["losses"] = {"model": NAME, "current_max_A": encode_array(600.0), "alpha_cu_per_K": encode_array(0.0039),
                         "copper_reference_C": encode_array(20.0),
                         **{k: encode_array(v) for k, v in coefficients.items()}}
    artifact = verify(seal({k: v for k, v in content.items() if k != "sha256"}))
    parameter = PERTURBATIONS["parameter"]
    assert parameter.subjects(artifact)[-2:] == ("qt_copper", "qt_iron_magnet")
    off = parameter.model(artifact, "qt_iron_magnet", 10.0)
    changed = {k for k in KEYS if off.array("losses", k, dtype=np.float64) != artifact.array("losses", k,
                                                                                              dtype=np.float64)}
    assert changed == {"qt_iron", "qt_magnet"}
    assert float(off.array("losses", "qt_iron", dtype=np.float64)) == pytest.approx(900.0 * 1.1)


@pytest.mark.slow
def test_a_kind_defined_in_a_test_runs_from_identification_to_the_emulated_firmware_bit_for_bit(
        quadratic_kind, default_data_dir):
    from bench.drive.dataset import load_dataset
    from bench.firmware.check import check_firmware
    from bench.firmware.codegen import generate
    from bench.firmware.toolchain import build_firmware
    from bench.model.artifact_values import artifact_loss_model
    from bench.model.identify import identify
    from bench.model.runs import drive_matrix, initial_temperatures
    from bench.motor.description import motor_from_dict
    from target_sim.artifact import seal, verify
    from target_sim.costs import step_cost
    from target_sim.model import run_offline

    motor = motor_from_dict(motor_file(quadratic_kind))
    assert motor.loss_kind == NAME and not motor.needs_currents
    train = [load_dataset(default_data_dir / f"cycle_coolant{c}.csv") for c in (20, 60)]
    ident = identify(train, motor=motor, swarm_size=8, pso_iterations=2, lm_iterations=2, seed=1)
    validation = load_dataset(default_data_dir / "cycle_coolant40.csv")
    initial = initial_temperatures(validation)
    for kind in ("lti-lptn", "hammerstein"):
        artifact = verify(seal(ident.content(kind)))
        assert artifact.loss_model == NAME and artifact.drive_signals == ("torque_Nm", "speed_rpm", "coolant_C",
                                                                          "ambient_C")
        # the lab reads its own section back as it wrote it
        model, _ = artifact_loss_model(artifact)
        assert model == QuadraticLosses(**{k: motor_file(NAME)["losses"][k] for k in KEYS})
        assert step_cost(artifact).blocks["losses"]["multiply"] > 8

        # 300 s of the FTP-75 after the preheat: torque and speed change every row
        drive = drive_matrix(validation, artifact.drive_signals)[9000:10500].astype(np.float32)
        assert np.unique(drive[:, :2], axis=0).shape[0] > 500
        _, outputs = run_offline(artifact, drive, initial)
        assert outputs.shape == (600, 4) and np.all(np.isfinite(outputs))
        assert np.ptp(outputs[:, 1]) > 1.0            # the winding heats up: the losses reached the network

        generated = generate(artifact)
        assert "quadratic_losses(torque, speed, table);" in generated.source and "LOSS_TABLES" not in generated.source
        report = check_firmware(artifact, build_firmware(generated).elf, drive, initial)
        assert report["steps"] == 600 and report["mismatches"] == 0
