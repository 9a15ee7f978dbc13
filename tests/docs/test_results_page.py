"""The results page and the README's headline table are built from the benchmark records, never typed by hand."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

import results_page  # noqa: E402


@pytest.fixture(scope="module")
def data_record(tmp_path_factory) -> dict:
    """A real record: `bench_data.py` (the quickest benchmark) run as a user runs it, writing to a temporary file."""
    out = tmp_path_factory.mktemp("records") / "data.json"
    done = subprocess.run([sys.executable, "tests/benchmarks/bench_data.py", "--json", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    # exit 1: its 30 s goal missed (a loaded machine); the record is written either way, and is what is tested here
    assert done.returncode in (0, 1) and out.exists(), done.stderr
    return json.loads(out.read_text(encoding="utf-8"))


def test_a_benchmark_writes_its_record_with_date_machine_code_and_load(data_record):
    assert data_record["benchmark"] == "data"
    assert data_record["date"].endswith("Z") and data_record["command"].startswith("python tests/benchmarks/")
    assert data_record["machine"]["cpus"] >= 1 and data_record["machine"]["python"].startswith("3.")
    assert set(data_record["load_average"]) == {"start", "end"}
    assert data_record["code"]["version"]
    assert set(data_record["figures"]["datasets"]) == {"20", "40", "60"}


def test_the_page_shows_the_records_figures_and_changes_with_them(data_record):
    page = results_page.render_results({"data": [data_record]})
    assert f"All three in {data_record['figures']['total_s']:.2f} s" in page
    assert data_record["machine"]["cpu"] in page and data_record["date"][:10] in page
    changed = copy.deepcopy(data_record)
    changed["figures"]["total_s"] = 123.45
    assert "All three in 123.45 s" in results_page.render_results({"data": [changed]})


def test_a_benchmark_without_a_record_says_how_to_measure_it():
    page = results_page.render_results({})
    for script in ("bench_accuracy.py", "bench_firmware.py", "bench_can.py", "bench_soak.py", "bench_memory.py"):
        assert f"Not measured yet: `python tests/benchmarks/{script}`" in page


def test_every_benchmark_script_has_a_section():
    scripts = {p.stem.removeprefix("bench_") for p in (ROOT / "tests" / "benchmarks").glob("bench_*.py")}
    assert scripts == set(results_page.BENCHMARKS)
    assert len(results_page.SECTIONS) == len(results_page.BENCHMARKS)


def test_the_committed_records_render_and_the_readme_table_is_theirs():
    records = results_page.load_records()
    assert records, "docs/results holds no record"
    results_page.render_results(records)
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert results_page.splice_readme(readme, results_page.render_headline(records)) == readme, (
        "README.md's headline table is stale: python docs/check_generated.py --write")


def test_splicing_replaces_only_the_marked_block():
    readme = f"# t\n\nbefore\n{results_page.README_BEGIN}\nold\n{results_page.README_END}\nafter\n"
    out = results_page.splice_readme(readme, f"{results_page.README_BEGIN}\nnew\n{results_page.README_END}\n")
    assert out == f"# t\n\nbefore\n{results_page.README_BEGIN}\nnew\n{results_page.README_END}\nafter\n"
    with pytest.raises(ValueError):
        results_page.splice_readme("# no markers\n", "x")


def test_the_observer_tables_come_from_the_record_and_change_with_it():
    record = results_page.load_records()["observer"][0]
    builtin = results_page.render_observer({"observer": [record]})
    pm = record["figures"]["builtin"]["runs"][0]["files"][0]["nodes"]["pm"]["open_loop"]
    assert "| open loop | " in builtin and f"{pm['rmse_C']:.3f} / {pm['max_abs_C']:.2f}" in builtin
    changed = copy.deepcopy(record)
    changed["figures"]["builtin"]["runs"][0]["files"][0]["nodes"]["pm"]["open_loop"]["rmse_C"] = 98.765
    assert "98.765 / " in results_page.render_observer({"observer": [changed]})
    forms = results_page.render_observer_forms({"observer": [record]})
    numerics = record["figures"].get("ipm", {}).get("numerics") or record["figures"]["builtin"]["numerics"]
    for row in numerics["rows"]:
        assert results_page._e(row["max_abs_f32_minus_f64_C"]) in forms, row["form"]
    assert "| open loop | " in results_page.render_observer_ipm({"observer": [record]})
    del changed["figures"]["ipm"]
    missing = "Not measured yet: `python tests/benchmarks/bench_observer.py`"
    assert missing in results_page.render_observer_ipm({"observer": [changed]})
    assert missing in results_page.render_observer({})


def _suite_record(data_record: dict) -> dict:
    """A suite record around data_record's provenance: one motor, one prior, one failed prior, the observer, a
    default against its alternative."""
    fig = {n: {"mse_K2": 1.25, "max_K": 3.5} for n in ("winding", "pm", "yoke", "tooth")}
    row = {"prior": "designer", "identify_s": 140.0, "test": {"hammerstein": fig, "lti-lptn": fig},
           "hammerstein_worse_on_validation": ["pm"]}
    observer = {"how": "estimated", "observer_s": 12.0,
                "pooled": {"winding": {"open_loop_mse_K2": 2.5, "observer_mse_K2": 0.4},
                           "pm": {"open_loop_mse_K2": 1.0, "observer_mse_K2": 0.9}}}
    defaults = {"regularization": {"prior": "designer", "default": {"hammerstein": {"winding": 0.5, "pm": 0.6}},
                                   "alternatives": {"fixed": {"hammerstein": {"winding": 0.7, "pm": 0.8}}}}}
    scores = {"winding": {"open_loop_mse_K2": 9.0, "observer_mse_K2": 0.5},
              "pm": {"open_loop_mse_K2": 4.0, "observer_mse_K2": 3.0}}
    pv = {n: {"mse_K2": 0.75, "max_K": 2.5} for n in ("winding", "pm", "yoke", "tooth")}
    deployed = {**row, "prior": "table1", "test": {**row["test"], "pv-lptn": pv}, "deployed_kind": "pv-lptn",
                "hammerstein_worse_on_validation": ["winding", "pm"]}
    motor = {"motor": "air-30kw", "priors": [{"prior": "auto", "failed": "bench identify failed (1): boom"}, row,
                                             deployed], "observer": [observer]}
    main = {**copy.deepcopy(data_record), "benchmark": "suite", "variant": None,
            "figures": {"motors": [motor], "complete": False}}
    compared = {**motor, "defaults": defaults,
                "observer_defaults": {"bias": {"default": "off", "scores": {"off": scores, "on": scores}}}}
    variant = {**copy.deepcopy(data_record), "benchmark": "suite", "variant": "defaults",
               "figures": {"motors": [compared], "complete": True}}
    return [variant, main]


def test_the_suite_section_shows_each_motor_prior_observer_and_default(data_record):
    page = results_page.render_results({"suite": _suite_record(data_record)})
    section = page[page.index("## The motor suite"):]
    cells = " | ".join(["1.25 / 3.50"] * 4)
    assert f"| air-30kw | designer | hammerstein | {cells} | pm | 140 |" in section    # a record before auto
    assert f"| air-30kw | designer | lti-lptn | {cells} |  |  |" in section
    # the kind --kind auto deployed is marked, and shown even when it is neither of the two compared
    assert f"| air-30kw | table1 | hammerstein | {cells} | winding, pm | 140 |" in section
    assert f"| air-30kw | table1 | pv-lptn (deployed) | {' | '.join(['0.75 / 2.50'] * 4)} |  |  |" in section
    assert "| air-30kw | auto | failed | Bench identify failed (1): boom |" in section
    assert "| air-30kw | estimated | 2.50 → 0.40 | 1.00 → 0.90 | 12 |" in section
    assert "| regularization: default | 0.50 / 0.60 |" in section
    assert "| regularization: fixed | 0.70 / 0.80 |" in section
    assert "This record is partial" in section
    assert "| open loop | 9.00 / 4.00 |" in section and "| bias: off (default) | 0.50 / 3.00 |" in section
    assert "- regularization: the default has the smallest winding + magnet MSE on 1 of 1 motors\n" in section
    assert "- bias: the default has the smallest winding + magnet MSE on 1 of 1 motors (no effect on 1" in section


def test_a_defaults_verdict_names_what_won_where_the_default_lost():
    sums = {"bias": {"air": ("output", {"output": 2.0, "off": 11.8}), "ipm": ("output", {"output": 3.0, "on": 2.5}),
                     "out": None}}
    [line, _] = results_page._verdicts(sums)
    assert line == ("- bias: the default has the smallest winding + magnet MSE on 1 of 2 motors; better: on on ipm "
                    "(2.50 against 3.00)")


def test_the_suite_folds_record_shows_the_identify_defaults_by_cross_validation(data_record):
    """`bench_suite.py --defaults --folds 3`: its own section, the figures named as the folds' mean, the verdicts."""
    folded = {"motor": "air-30kw", "priors": [], "defaults": {"loss-scales": {
        "prior": "designer", "held": [], "default": {"hammerstein": {"winding": 15.97, "pm": 24.99}},
        "alternatives": {"fit": {"hammerstein": {"winding": 10.65, "pm": 21.95}}}, "folds": {"count": 3}}}}
    records = _suite_record(data_record) + [{**copy.deepcopy(data_record), "benchmark": "suite", "variant": "folds",
                                             "parameters": {**data_record["parameters"], "folds": 3},
                                             "figures": {"motors": [folded], "complete": True}}]
    page = results_page.render_results({"suite": records})
    section = page[page.index("--folds 3"):]
    assert "mean of 3 folds' held-out profiles" in section
    assert "| loss-scales: default | 15.97 / 24.99 |" in section and "| loss-scales: fit | 10.65 / 21.95 |" in section
    assert "- loss-scales: the default has the smallest winding + magnet MSE on 0 of 1 motors; better: fit on " \
           "air-30kw (32.60 against 40.96)" in section


def test_the_suite_floor_shows_each_motors_in_sample_test_figures_and_whether_the_goal_is_reachable(data_record):
    """`bench_suite.py --floor`: per motor and kind the in-sample test figures; a failed motor says so."""
    missed = {n: {"mse_K2": 7.06, "max_K": 7.76} for n in ("winding", "pm", "yoke", "tooth")}
    met = {n: {"mse_K2": 1.5, "max_K": 4.0} for n in ("winding", "pm", "yoke", "tooth")}
    motors = [{"motor": "air-30kw", "floor": {"test_in_sample": {"hammerstein": missed, "lti-lptn": missed},
                                              "goal_reachable": False}},
              {"motor": "ipm-60kw", "floor": {"test_in_sample": {"hammerstein": met}, "goal_reachable": True}},
              {"motor": "outrunner", "floor": {"failed": "bench identify failed (1): boom"}}]
    records = _suite_record(data_record) + [{**copy.deepcopy(data_record), "benchmark": "suite", "variant": "floor",
                                             "figures": {"motors": motors, "complete": True}}]
    page = results_page.render_results({"suite": records})
    section = page[page.index("## The motor suite"):]
    assert "model class's floor" in section
    assert f"| air-30kw | hammerstein | {' | '.join(['7.06 / 7.76'] * 4)} | no |" in section
    assert f"| air-30kw | lti-lptn | {' | '.join(['7.06 / 7.76'] * 4)} |  |" in section
    assert f"| ipm-60kw | hammerstein | {' | '.join(['1.50 / 4.00'] * 4)} | yes |" in section
    assert "| outrunner | – | failed |" in section


def test_the_sitting_section_shows_each_round_the_medians_and_the_goals():
    """The performance sitting's section: every round's rows/s with its ratio to the ping-pong, the medians, and
    whether each goal was met, all from the record."""
    record = copy.deepcopy(results_page.load_records()["sitting"][0])
    page = "\n".join(results_page.section_sitting({"sitting": [record]}))
    quiet = record["figures"]["medians"]["quiet"]
    assert f"({quiet['ratio_python']:.3f})" in page
    assert results_page._n(quiet["pingpong_round_trips_per_s"]) in page
    assert page.count("| quiet ") + page.count("| loaded ") == 2 + sum(map(len, record["figures"]["rounds"].values()))
    record["figures"]["goals_met"]["quiet"] = not record["figures"]["goals_met"]["quiet"]
    changed = "\n".join(results_page.section_sitting({"sitting": [record]}))
    assert changed != page and ("quiet (met)" in changed) != ("quiet (met)" in page)


def test_the_seed_spread_is_the_mean_over_folds_of_the_seeds_range():
    """bench_suite.seed_spread: per fold the Hammerstein winding + magnet range over the seeds, averaged over folds;
    None with one seed."""
    sys.path.insert(0, str(ROOT / "tests" / "benchmarks"))
    from bench_suite import seed_spread

    def run(w, m):
        return {"hammerstein": {"winding": w, "pm": m}, "lti-lptn": {"winding": 99.0, "pm": 99.0}}

    assert seed_spread([[run(1, 2), run(2, 4)], [run(10, 10), run(4, 6)]]) == (3 + 10) / 2
    assert seed_spread([[run(1, 2)], [run(3, 4)]]) is None


def test_a_setting_without_a_swarm_is_identified_once_for_every_seed():
    """bench_suite.seedless: --swarm 0 (alone or with other arguments) has no seed to vary; any other setting has."""
    sys.path.insert(0, str(ROOT / "tests" / "benchmarks"))
    from bench_suite import seedless

    assert seedless(("--swarm", "0")) and seedless(("--freeze", "yes", "--swarm", "0", "--prior-factor", "2"))
    assert not seedless(("--prior-factor", "2")) and not seedless(("--swarm", "20")) and not seedless(())
    assert not seedless(("--seed", "0", "--swarm", "1"))


def test_an_alternative_wins_only_beyond_t0_standard_errors_of_the_paired_differences():
    """bench_suite.paired_verdict: per fold and seed the alternative's score minus the default's; a win only when the
    mean difference is beyond t0 (2.306 for nine pairs) standard errors; the page says per motor which side won."""
    sys.path.insert(0, str(ROOT / "tests" / "benchmarks"))
    from bench_suite import paired_verdict

    def folds(*scores):   # three folds × three seeds, each score all on the winding
        return [[{"hammerstein": {"winding": x, "pm": 0.0}} for x in scores[i:i + 3]] for i in (0, 3, 6)]

    base = folds(10, 12, 11, 3, 2, 4, 80, 60, 100)
    steady = paired_verdict(base, folds(9, 11, 10, 2.2, 1, 3.1, 79, 58.9, 99))     # 1 lower, always: t ≪ −t0
    assert steady["verdict"] == "alternative" and steady["t0"] == 2.306 and steady["pairs"] == 9
    noisy = paired_verdict(base, folds(1, 3, 2, 1, 1, 1, 140, 20, 60))              # lower on average, not steadily
    assert noisy["verdict"] == "not beyond t0 standard errors" and noisy["mean_difference_K2"] < 0
    assert paired_verdict(folds(9, 11, 10, 2.2, 1, 3.1, 79, 58.9, 99), base)["verdict"] == "default"
    lost = [[{"lti-lptn": {}}] * 3] * 3
    assert paired_verdict(base, lost)["verdict"] == "no hammerstein figures"
    motors = [{"motor": motor, "defaults": {"freeze": {"verdict": {"yes": verdict}}}}
              for motor, verdict in (("a", steady), ("b", noisy))]
    (line,) = [x for x in results_page._seeded_verdicts(motors) if x]
    assert "better on 1, worse on 0 of 2 motors" in line and "t0 standard errors" in line
    assert f"a {steady['default_K2']:.2f} → {steady['alternative_K2']:.2f}" in line


def test_records_judged_by_the_seeds_margin_keep_their_verdicts_on_the_page():
    """A folds record made before the standard-error form (its verdicts carry a margin) is shown as it was judged."""
    old = {"default_K2": 15.0, "alternative_K2": 2.0, "margin_K2": 1.0, "verdict": "alternative"}
    motors = [{"motor": "a", "defaults": {"hammerstein-poles": {"verdict": {"fixed": old}}}}]
    (line,) = [x for x in results_page._seeded_verdicts(motors) if x]
    assert "beyond the seeds' spread: better on 1" in line and "margin 1.00" in line


def test_the_rejudged_comparisons_each_have_a_row_with_their_verdict_then_and_now():
    """`bench_suite.py --rejudge`'s record: one row per record, motor and alternative on the suite section."""
    suite = results_page.load_records()["suite"]
    record = next(r for r in suite if r.get("variant") == "rejudged")
    page = "\n".join(results_page.section_suite({"suite": suite}))
    judged = record["figures"]["rejudged"]
    assert len(judged) >= 6 and sum(line.count(j["verdict_then"]) > 0 for j in judged for line in [page]) == len(judged)
    for j in judged:
        assert f"{j['mean_difference_K2']:+.2f} ± {j['standard_error_K2']:.2f} (t {j['t']:+.2f})" in page


def test_folds_records_of_different_comparisons_each_keep_their_section(data_record):
    """Comparisons run on different days (and code) keep their own records, variant "folds-<defaults compared>"
    (`bench_suite.folds_variant`), and the page shows every one of them."""
    sys.path.insert(0, str(ROOT / "tests" / "benchmarks"))
    from bench_suite import folds_variant

    assert folds_variant(None) == "folds"
    assert folds_variant(["regularization-auto", "regularization"]) == "folds-regularization"
    assert folds_variant(["loss-scales", "hammerstein-poles-auto"]) == "folds-hammerstein-poles-loss-scales"
    assert folds_variant(["stator-weight"], seeds=3) == "folds-stator-weight-seeds3"
    rows = {}
    for variant, name, figure in (("folds", "loss-scales", 15.97), ("folds-regularization", "regularization", 7.25)):
        motor = {"motor": "air-30kw", "priors": [], "defaults": {name: {
            "prior": "designer", "held": [], "default": {"hammerstein": {"winding": figure, "pm": 1.0}},
            "alternatives": {"fixed": {"hammerstein": {"winding": 9.0, "pm": 1.0}}}, "folds": {"count": 3}}}}
        rows[variant] = {**copy.deepcopy(data_record), "benchmark": "suite", "variant": variant,
                         "parameters": {**data_record["parameters"], "folds": 3},
                         "figures": {"motors": [motor], "complete": True}}
    page = results_page.render_results({"suite": _suite_record(data_record) + list(rows.values())})
    assert page.count("--defaults --folds 3 --hold-test") == 2
    assert "| loss-scales: default | 15.97 / 1.00 |" in page and "| regularization: default | 7.25 / 1.00 |" in page


def test_a_benchmark_stopped_with_sigterm_leaves_no_child_and_no_work_directory(tmp_path):
    """`kill` of a benchmark script (record.Record installs the handler) unwinds it as Ctrl-C would: the `bench`
    child it waits for is killed and its temporary directory removed (before, both stayed behind)."""
    import os
    import signal
    import time

    script = tmp_path / "stopped.py"
    script.write_text(
        "import argparse, subprocess, sys, tempfile\n"
        f"sys.path.insert(0, {str(ROOT / 'tests' / 'benchmarks')!r})\n"
        "from record import Record, add_record_arguments\n"
        "parser = argparse.ArgumentParser(); add_record_arguments(parser)\n"
        "Record('stopped', parser.parse_args(['--no-json']))\n"
        f"with tempfile.TemporaryDirectory(dir={str(tmp_path)!r}) as work:\n"
        "    child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)'])\n"
        "    print(work, child.pid, flush=True)\n"
        "    child.wait()\n"
        "    subprocess.run([sys.executable, '-c', 'import time; time.sleep(120)'])\n")
    runner = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    work, pid = runner.stdout.readline().split()     # waited for: the script has its child and its directory
    os.kill(int(pid), signal.SIGKILL)                  # the first child ends; the script starts the second
    time.sleep(1.0)
    runner.send_signal(signal.SIGTERM)
    assert runner.wait(timeout=60) == 128 + signal.SIGTERM
    assert not Path(work).exists()
    deadline = time.monotonic() + 30
    while any("time.sleep(120)" in _cmdline(p) for p in Path("/proc").glob("[0-9]*")):
        assert time.monotonic() < deadline, "the benchmark's child outlived it"
        time.sleep(0.2)


def _cmdline(proc: Path) -> str:
    try:
        return (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""
