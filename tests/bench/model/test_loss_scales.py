"""Loss scales (bench.model.loss_scales): the stator iron and magnet losses fitted with the network, the runs and
the loss models scaled alike, on runs simulated from a known network whose losses were off by known factors."""

import numpy as np
import pytest

from bench.model.loss_scales import SCALED_LOSSES, ScaledResiduals, fit_loss_scales, scaled_runs
from bench.model.lptn_fit import LptnFit, discrete_blocks, log_scaled, measured_nodes, parameter_bounds, to_search
from bench.model.polish import Residuals
from bench.model.runs import ModelRun
from bench.motor.losses import MAP_TABLES, ElectricalLosses, LossMaps
from bench.motor.losskinds import LAB_LOSS_KINDS
from bench.thermal.estimator import StepInputs, identity_sigmoid, loop_parameters, run_batch
from bench.thermal.parameters import LptnParameters

# the IPM example's true network (as tests/bench/model/test_identification_method.py)
TRUTH = LptnParameters(C_y=2800.0, C_w=2400.0, C_t=1400.0, C_m=4800.0, R_yw=0.022, R_yt=0.02, R_wt=0.12,
                       R_cy0=0.01, R_wm0=0.5, a_wm=0.35, b_wm=0.8, R_tm0=0.9, a_tm=0.5, b_tm=0.35, R_ma0=2.0,
                       a_ma=1.0, b_ma=-0.2, alpha_cy=-0.006, k_0=0.72, k_1=-0.06, k_2=-0.01, k_3=-0.1)
DT = 2.0
STEPS = 3000
OFF = {"p_stator": 0.7, "p_magnet": 1.5}     # the plant's losses against the loss model's


def _run(seed: int) -> ModelRun:
    """Piecewise-constant losses: the references simulated with the losses times OFF, the run carrying the
    model's (unscaled) losses, 0.1 °C noise."""
    rng = np.random.default_rng(seed)
    hold = 150
    levels = rng.random((STEPS // hold + 1, 3))
    copper = np.repeat(levels[:, 0] * 1500.0, hold)[:STEPS]
    iron = np.repeat(levels[:, 1] * 600.0, hold)[:STEPS]
    magnet = np.repeat(levels[:, 2] * 300.0, hold)[:STEPS]
    coolant = np.full(STEPS, 30.0 + 10.0 * seed)
    inputs = StepInputs(table_losses=np.column_stack([copper, 0.1 * copper, iron, magnet, copper / 10.0]),
                        speed_ratio=np.repeat(levels[:, 1], hold)[:STEPS], coolant=coolant,
                        ambient=np.full(STEPS, 25.0), current_max=400.0)
    initial = np.full(4, coolant[0])
    model = ModelRun(f"run{seed}", DT, inputs, (np.arange(STEPS) + 1) * DT, np.zeros(STEPS), np.zeros(STEPS),
                     initial)
    plant = scaled_runs([model], OFF)[0]
    a_d, b_d = discrete_blocks(np.array([TRUTH.as_vector()]), DT)
    _, traj = run_batch(a_d, b_d, np.eye(4)[None], loop_parameters(TRUTH)[None], identity_sigmoid(np.ones(4))[None],
                        plant.inputs, initial, keep_trajectories=True)
    y = traj[0] + rng.normal(0.0, 0.1, traj[0].shape)
    return ModelRun(model.name, DT, inputs, model.step_time_s, y[:, 1], y[:, 3], initial, y[:, 0], y[:, 2])


@pytest.fixture(scope="module")
def runs():
    return [_run(seed) for seed in range(2)]


def test_scaled_runs_multiply_only_the_named_losses(runs):
    scaled = scaled_runs(runs, {"p_magnet": 2.0})[0]
    table, original = scaled.inputs.table_losses, runs[0].inputs.table_losses
    magnet = MAP_TABLES.index("p_magnet")
    assert np.array_equal(table[:, magnet], 2.0 * original[:, magnet])
    others = [i for i in range(table.shape[1]) if i != magnet]
    assert np.array_equal(table[:, others], original[:, others])
    assert runs[0].inputs.table_losses is original      # the input runs are left alone


def test_a_batch_of_mixed_factors_is_each_model_on_its_own_scaled_runs(runs):
    """The residuals group the models by their factors: each row is what the plain residuals give on runs scaled
    by that row's factors, bit for bit, whatever else is in the batch."""
    bounds = parameter_bounds(TRUTH, (0.3, 3.0))
    scaled = log_scaled(bounds)
    nodes = measured_nodes(runs)
    network = to_search(np.array(TRUTH.as_vector()), scaled)
    factors = [(0.0, 0.0), (np.log(0.7), np.log(1.5)), (0.0, 0.0), (0.1, -0.2)]
    coords = np.array([np.concatenate([network, f]) for f in factors])
    errors = ScaledResiduals(runs, DT, nodes, scaled).errors(coords)
    for row, (iron, magnet) in zip(errors, factors, strict=True):
        alone = Residuals(scaled_runs(runs, {"p_stator": np.exp(iron), "p_magnet": np.exp(magnet)}), DT, nodes,
                          scaled).errors(network[None])[0]
        assert row.tobytes() == alone.tobytes()


def test_the_fit_finds_the_factors_the_plant_had(runs):
    """From the true network with the model's losses (factors 1), the fit moves to the plant's factors and the
    cost falls; a fit that could not move them would stay at 1."""
    start = TRUTH.with_values(R_yt=0.026, R_ma0=2.6)
    fit = LptnFit(start, 0.0, [], 0, 0, 0, 0, parameter_bounds(TRUTH, (0.3, 3.0)), [], measured_nodes(runs))
    fitted, scales = fit_loss_scales(fit, runs, DT, TRUTH)
    assert set(scales.factors) == set(SCALED_LOSSES)
    for name, factor in OFF.items():
        assert scales.factors[name] == pytest.approx(factor, rel=0.05)
    assert scales.cost < scales.cost_before - 1.0
    assert fitted.cost == scales.cost and fitted.params != start


def test_each_loss_kind_scales_its_model_as_the_runs_are_scaled():
    columns = {"speed_rpm": np.array([0.0, 3000.0, 9000.0]), "i_d_A": np.array([0.0, -50.0, -120.0]),
               "i_q_A": np.array([0.0, 150.0, 60.0]), "torque_Nm": np.array([0.0, 80.0, 20.0])}
    electrical = ElectricalLosses(pole_pairs=4.0, stator_resistance_ohm=0.015, ac_factor=0.3, ac_reference_Hz=900.0,
                                  iron_hysteresis_W=120.0, iron_eddy_W=80.0, iron_reference_Hz=200.0,
                                  iron_current_factor=1.0, magnet_W=900.0, magnet_reference_Hz=900.0,
                                  magnet_no_load_share=0.4, current_max_A=400.0)
    grid = (np.array([0.0, 100.0]), np.array([0.0, 10000.0]))
    maps = LossMaps(*grid, {name: np.array([[1.0, 2.0], [3.0, 4.0]]) * (k + 1) for k, name in enumerate(MAP_TABLES)})
    for model in (electrical, maps):
        kind = LAB_LOSS_KINDS[model.kind]
        before = model.evaluate_columns(columns)
        after = kind.scaled(model, OFF).evaluate_columns(columns)
        for name in MAP_TABLES:
            np.testing.assert_allclose(after[name], before[name] * OFF.get(name, 1.0), rtol=1e-12, atol=0)
        with pytest.raises(ValueError, match="current"):
            kind.scaled(model, {"current": 2.0})
