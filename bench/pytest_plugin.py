"""The bench as a pytest plugin: a `thermal_bench` fixture that runs the bench against a target and returns the typed
results, so one test file runs unchanged against the Python target, the emulated firmware, or a target on a bus.

On when the package is installed (the `pytest11` entry point `bench`), off with `-p no:bench`; from a source tree,
`-p no:bench -p bench.pytest_plugin` (the `no:bench` keeps an installed entry point from registering it twice).
Where the target is:

    pytest                                       a target the bench starts, the Python engine (default)
    pytest --bench-engine firmware               ... the firmware engine in the emulated Cortex-M4F
    pytest --bench-interface udp_multicast --bench-channel 239.74.163.2 [--bench-bitrate N]
           [--bench-bus-kwargs port=43113]       a target already on that bus (a real ECU, or any node posing
                                                 as one): the bench is its host (`bench host`)
    pytest --bench-profile bench.toml            the same, from a TOML file (see `load_profile`)

    def test_magnet(thermal_bench):
        result = thermal_bench.run(rows=600, criteria="criteria.toml")
        assert result.clean, result.verdict
        assert result.metrics.accuracy.rmse_C.magnet < 3.0

`thermal_bench.run(data=…, model=…, rows=…, faults=…)` runs `python -m bench run` (a started target) or
`python -m bench host` (an attached one) with --json in a subprocess and returns a `BenchRun`: the exit status and
the `RunSummary` (`bench.analysis.results`), with the acceptance criteria when `criteria` or `baseline` is given.
A run the bench refuses (exit status 2, or a target that could not be reached) raises `BenchRunError` with the
bench's one sentence. The bench dies with the process that runs the test (`dbc.lifeline`: it gets SIGTERM when
pytest is terminated or killed, a CI job cancelled, and stops its target and removes its partial log); a run past its
`timeout` is stopped with SIGTERM, with SIGKILL of its process group only after `STOP_GRACE_S`, and what it left is
removed (`stop_bench`). The run's figures go into pytest's JUnit XML as properties of the test (`record_property`:
`bench_clean`, `bench_rmse_C_magnet`, `bench_cycles`, one `bench_criterion_NAME` per criterion, ...) with
`-o junit_family=xunit1`; under pytest's default xunit2, whose schema has no properties in a testcase, as properties
of the suite named `NODEID::bench_...`.

Marker: `@pytest.mark.bench_engines("python", "firmware", "external")` runs a test only against those targets
("external": an attached one); others skip it. Runs against an attached target take turns across pytest-xdist
workers (a file lock per bus): the target answers one host at a time.
"""

from __future__ import annotations

import difflib
import hashlib
import os
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from bench.errors import BenchError
from bench.run.child import STOP_GRACE_S, bench_command, run_summary, start_bench, stop_bench_process
from bench.run.request import HOST, OPTION, RUN, SETTABLE, RunRequest
from bench.tomlspec import Check, TableSpec, flag, number, read_spec, spec_tables, string, whole_at_least
from bench.tomlspec import path as path_value
from dbc.files import same_file
from dbc.transport import bus_interfaces

TARGETS = ("python", "firmware", "external")
MARKER = "bench_engines"
# [run]: every run option a user sets (`bench.run.request`), and how long a run may take
DEFAULT_TIMEOUT_S = 900.0
# an attached target that is still starting (a loaded CI runner) is waited for this long: `bench host`'s own
# default (15 s) is for a target known to run
ATTACHED_CONNECT_TIMEOUT_S = 120.0
USAGE_STATUS = 2


class BenchRunError(BenchError):
    """The bench refused a run or could not make it (its one sentence, the bench's exit status)."""

    def __init__(self, sentence: str, status: int | None):
        super().__init__(sentence)
        self.status = status


@dataclass(frozen=True)
class BenchConfig:
    """Where the target is and what every run defaults to: the command line's --bench-* options over a profile."""

    engine: str = "python"
    attach: bool = False
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    bus_kwargs: dict[str, Any] = field(default_factory=dict)
    defaults: dict[str, Any] = field(default_factory=dict)   # run options of the profile's [run]
    out_dir: Path | None = None

    @property
    def target(self) -> str:
        """'python' or 'firmware' (a target the bench starts), 'external' (one already on the bus)."""
        return "external" if self.attach else self.engine

    def bus_argv(self) -> list[str]:
        argv = []
        if self.interface is not None:
            argv += ["-i", self.interface]
        if self.channel is not None:
            argv += ["-c", str(self.channel)]
        if self.bitrate is not None:
            argv += ["-b", str(self.bitrate)]
        if self.bus_kwargs:
            argv += ["--bus-kwargs", *(f"{k}={v}" for k, v in self.bus_kwargs.items())]
        return argv

    def describe(self) -> str:
        if not self.attach:
            return f"a {self.engine} target the bench starts" + (f" on {self.interface}" if self.interface else "")
        return f"the target on {' '.join(self.bus_argv())}"


def load_profile(path: Path) -> dict[str, Any]:
    """A TOML profile: where the target is and the runs' defaults (pytest.UsageError, one sentence, if bad).

        [target]
        engine = "firmware"          # python or firmware: a target the bench starts
        attach = true                # or: the target already on [bus] (default: true when [bus] is given)
        [bus]
        interface = "udp_multicast"
        channel = "239.74.163.2"
        bitrate = 500000
        bus_kwargs = { port = 43113 }
        [run]                        # defaults of thermal_bench.run (paths relative to the profile)
        rows = 1500
        criteria = "criteria.toml"
    """
    path = Path(path)
    text = read_spec(path, "--bench-profile", "give the path of a TOML profile", pytest.UsageError)
    doc = spec_tables(text, f"--bench-profile {path}", PROFILE_KEYS, pytest.UsageError, fix="fix the profile",
                      unknown="has an unknown section {key!r}; a profile has the tables {tables}")
    out: dict[str, Any] = {}
    for section, spec in profile_tables(path.parent).items():
        if section in doc:    # checked, at start and naming the profile: not a failure of every test at run time
            out[section] = spec.read(doc[section], f"--bench-profile {path}", pytest.UsageError)
    return out


# the [run] keys that name files (relative to the profile, they must exist); the profile's own key, the time limit
RUN_FILES = ("data", "model", "mapping", "criteria", "baseline")


def profile_tables(base: Path) -> dict[str, TableSpec]:
    """A profile's tables: [target] and [bus] (checked further against pytest's options in `config_of`), and [run],
    whose keys are the run request's own options with their own checks (the words a campaign spec's key gets), its
    files relative to `base` (they must exist), and the profile's own time limit."""
    run: dict[str, Check] = {key: OPTION[key].check for key in SETTABLE}
    run.update({key: _existing_file(base) for key in RUN_FILES}, timeout=_seconds)
    return {"target": TableSpec("[target]", {"engine": string, "attach": flag}),
            "bus": TableSpec("[bus]", {"interface": string, "channel": _channel, "bitrate": whole_at_least(1),
                                       "bus_kwargs": _table}),
            "run": TableSpec("[run]", run)}



def _existing_file(base: Path) -> Check:
    def check(value: Any) -> str:
        where = base / path_value(value)
        if not where.exists():
            raise ValueError(f"{value!r} does not exist (a path relative to the profile)")
        return str(where)
    return check


def _seconds(value: Any) -> float:
    if number(value, positive=False) <= 0:
        raise ValueError("must be a number of seconds above 0")
    return float(value)


def _channel(value: Any) -> str | int:
    if isinstance(value, bool) or not isinstance(value, str | int):
        raise ValueError("must be a string or a whole number")
    return value


def _table(value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError("must be a table, e.g. { port = 43113 }")
    return value


# each table's keys (a profile's sections, in order)
PROFILE_KEYS = {section: tuple(spec.keys) for section, spec in profile_tables(Path()).items()}


def _bus_kwargs(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise pytest.UsageError(f"--bench-bus-kwargs {item!r} must be KEY=VALUE, e.g. port=43113")
        out[key] = value
    return out


def config_of(options) -> BenchConfig:
    """The BenchConfig of pytest's options (`config.option`): the command line over the profile."""
    if options.bench_profile and options.bench_out and same_file(options.bench_profile, options.bench_out):
        raise pytest.UsageError(f"--bench-out {options.bench_out} is the same file as --bench-profile "
                                f"{options.bench_profile} (the profile would be overwritten); choose another "
                                "--bench-out directory")
    profile = load_profile(Path(options.bench_profile)) if options.bench_profile else {}
    target, bus, run = profile.get("target", {}), profile.get("bus", {}), profile.get("run", {})
    interface = options.bench_interface or bus.get("interface")
    if interface is not None and interface not in bus_interfaces():
        near = difflib.get_close_matches(str(interface), bus_interfaces(), n=1)
        hint = f"did you mean {near[0]!r}? " if near else ""
        raise pytest.UsageError(f"the bench interface {interface!r} (--bench-interface or [bus] interface) is not a "
                                f"python-can interface; {hint}use one of {', '.join(bus_interfaces())}")
    engine = options.bench_engine or target.get("engine") or "python"
    if engine not in ("python", "firmware"):
        raise pytest.UsageError(f"the bench engine {engine!r} is neither python nor firmware")
    # a bus given and no engine asked for: the target is already there (attach); an engine too: start one on it
    attach = bool(target.get("attach", interface is not None and not (options.bench_engine or target.get("engine"))))
    if attach and interface is None:
        raise pytest.UsageError("attaching to a target needs its bus: --bench-interface (or [bus] interface in "
                                "--bench-profile)")
    bitrate = options.bench_bitrate or bus.get("bitrate")
    kwargs = {**bus.get("bus_kwargs", {}), **_bus_kwargs(options.bench_bus_kwargs or [])}
    return BenchConfig(engine=engine, attach=attach, interface=interface,
                       channel=options.bench_channel or bus.get("channel"),
                       bitrate=int(bitrate) if bitrate else None, bus_kwargs=kwargs, defaults=run,
                       out_dir=Path(options.bench_out) if options.bench_out else None)


# ---------------------------------------------------------------- the runs


@dataclass
class BenchRun:
    """One run of the bench: how it was made, its exit status and its typed summary."""

    argv: list[str]
    exit_status: int
    summary: Any            # bench.analysis.results.RunSummary
    stderr: str
    junit_xml: Path | None = None

    @property
    def metrics(self):
        return self.summary.metrics

    @property
    def clean(self) -> bool:
        return self.summary.clean

    @property
    def verdict(self) -> str:
        return self.summary.verdict

    @property
    def acceptance(self):
        return self.summary.metrics.acceptance

    @property
    def passed(self) -> bool:
        """The bench's exit status was 0: clean (or tolerated) and every acceptance criterion met."""
        return self.exit_status == 0


@contextmanager
def _bus_turn(config: BenchConfig) -> Iterator[None]:
    """One run at a time on an attached target's bus, across processes (pytest-xdist workers)."""
    if not config.attach:
        yield
        return
    import fcntl  # here, not at the top: every pytest session of the venv loads the plugin (Windows has none)

    key = hashlib.sha256(" ".join(config.bus_argv()).encode()).hexdigest()[:16]
    with open(Path(tempfile.gettempdir()) / f"thermal-bench-{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def run_bench(argv: list[str], timeout_s: float, log: Path) -> subprocess.CompletedProcess:
    """`argv` (a `python -m bench ...`, `bench.run.child.bench_command`) to its end, output captured. The bench dies
    with this process (`bench.run.child.start_bench`: it gets SIGTERM when pytest is terminated or killed, and stops
    its target and removes its partial log itself). On a timeout or an interruption (Ctrl-C, pytest stopping) it is
    stopped like a user would (`stop_bench`); subprocess.TimeoutExpired then carries in `output` the sentence of how
    it was stopped."""
    proc = start_bench(argv, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise subprocess.TimeoutExpired(argv, timeout_s, output=stop_bench(proc, log)) from None
    except BaseException:
        stop_bench(proc, log)
        raise
    return subprocess.CompletedProcess(argv, proc.returncode, stdout, stderr)


def stop_bench(proc: subprocess.Popen, log: Path, grace_s: float = STOP_GRACE_S) -> str:
    """Stop a running bench (`bench.run.child.stop_bench_process`: SIGTERM, after `grace_s` SIGKILL of its whole
    process group); then remove what a killed bench leaves (its partial `log`, its scratch directory) once nothing
    of the group runs. How it stopped, as a sentence."""
    _, _, killed = stop_bench_process(proc, grace_s)
    from bench.run.leftovers import remove_stale_partials, remove_stale_scratch

    remove_stale_partials(log)
    remove_stale_scratch()
    if killed:
        return f"it did not stop within {grace_s:g} s of SIGTERM and was killed (SIGKILL)"
    return "it was stopped with SIGTERM"


def _one_sentence(stderr: str, status: int) -> str:
    lines = [line for line in stderr.splitlines() if line.startswith("bench") and "error" in line]
    last = lines[-1] if lines else (stderr.strip().splitlines() or [f"exit status {status}"])[-1]
    return last.removeprefix("bench: error: ")


class ThermalBench:
    """The `thermal_bench` fixture: `run` the bench against the session's target, figures recorded for pytest."""

    def __init__(self, config: BenchConfig, out_dir: Path, record_property=None):
        self.config = config
        self.out_dir = Path(out_dir)
        self._record = record_property
        self.runs: list[BenchRun] = []

    @property
    def target(self) -> str:
        return self.config.target

    def argv(self, *, run_dir: Path, faults: str | dict[str, float] | None = None, tolerate_faults: bool = False,
             report: bool = False, **options: Any) -> list[str]:
        """The `python -m bench ...` command line of one run: the profile's [run] options, then `options` (any run
        option of `bench.run.request`, None for the profile's), the log, report and JUnit XML in `run_dir`."""
        attach = self.config.attach
        command = HOST if attach else RUN
        chosen = {k: v for k, v in self.config.defaults.items() if k in OPTION}
        chosen |= {k: v for k, v in options.items() if v is not None}
        if faults:
            chosen["faults"] = faults
        if tolerate_faults:
            chosen["tolerate_faults"] = True
        if chosen.get("data") is None and attach:   # `bench host` needs its data named; `bench run` generates it
            from bench.drive.generate import ensure_default_datasets

            chosen["data"] = ensure_default_datasets(Path("out/data"))[40]
        if attach:   # an attached target may still be starting
            chosen.setdefault("connect_timeout", ATTACHED_CONNECT_TIMEOUT_S)
        else:
            chosen["engine"] = self.config.engine
        chosen |= {"log": run_dir / "bench.blf", "junit_xml": run_dir / "junit.xml", "no_report": not report}
        if report:
            chosen["report"] = run_dir / "report"
        request = RunRequest.from_mapping(chosen, "thermal_bench.run")
        argv = bench_command([command, *request.to_argv(command), "--json", "--quiet", *self.config.bus_argv()])
        if not attach and self.config.interface is None:
            argv += ["-i", "udp_multicast"]   # a run-unique port: parallel tests never meet
        return argv

    def run(self, data: str | Path | None = None, model: str | Path | None = None, rows: int | None = None,
            faults: str | dict[str, float] | None = None, *, tolerate_faults: bool = False, report: bool = False,
            timeout: float | None = None, **options: Any) -> BenchRun:
        """Run the bench once (`bench run` on a started target, `bench host` on an attached one) and return its
        typed results; `options`: any other run option (`bench.run.request`: mode, criteria, baseline, isr_rate,
        reply_timeout, ...). BenchRunError (the bench's sentence) for a run it refused or could not make."""
        run_dir = self.out_dir / f"run{len(self.runs) + 1}"
        run_dir.mkdir(parents=True, exist_ok=True)
        argv = self.argv(data=data, model=model, rows=rows, faults=faults, tolerate_faults=tolerate_faults,
                         report=report, run_dir=run_dir, **options)
        limit = timeout or float(self.config.defaults.get("timeout", DEFAULT_TIMEOUT_S))
        with _bus_turn(self.config):
            try:
                proc = run_bench(argv, limit, run_dir / "bench.blf")
            except subprocess.TimeoutExpired as exc:
                raise BenchRunError(f"the bench did not finish within {limit:g} s ({' '.join(argv[2:4])} on "
                                    f"{self.config.describe()}); {exc.output}", None) from None
        result = self._result(argv, proc, run_dir)
        self.runs.append(result)
        self._record_figures(result)
        _print_attachments(result)
        return result

    def _result(self, argv: list[str], proc: subprocess.CompletedProcess, run_dir: Path) -> BenchRun:
        data = run_summary(proc.returncode, proc.stdout)
        if data is None:     # refused, crashed, or no JSON: the bench's own sentence
            raise BenchRunError(_one_sentence(proc.stderr, proc.returncode), proc.returncode)
        from bench.analysis.results import RunSummary

        if "metrics" not in data:   # a run whose log held no figures (`bench host`)
            raise BenchRunError("the host's log could not be compared with the model: " + "; ".join(data["problems"]),
                                1)
        summary = RunSummary.from_json(data)   # `bench run --json` and `bench host --json` print one shape
        junit = run_dir / "junit.xml"
        return BenchRun(argv, proc.returncode, summary, proc.stderr, junit if junit.is_file() else None)

    def _record_figures(self, result: BenchRun) -> None:
        if self._record is None:
            return
        prefix = "bench" if len(self.runs) == 1 else f"bench_run{len(self.runs)}"
        for name, value in figures(result).items():
            self._record(f"{prefix}_{name}", value)


def _print_attachments(result: BenchRun) -> None:
    """The run's log, report and JUnit XML as `[[ATTACHMENT|path]]` lines on the test's output, relative to the
    project directory: with `-o junit_logging=system-out` pytest's JUnit XML carries them, and GitLab and Jenkins
    attach the files to the test."""
    from bench.acceptance.junit import attachment_path

    for path in (result.metrics.integrity.log, result.metrics.report, result.junit_xml):
        if path:
            print(f"[[ATTACHMENT|{attachment_path(path)}]]")


def figures(result: BenchRun) -> dict[str, Any]:
    """The run's figures as flat name -> value pairs (pytest's JUnit properties)."""
    from bench.acceptance.kinds.cycles import step_cycles
    from dbc.contract import TEMPERATURE_NODES

    m = result.metrics
    out: dict[str, Any] = {"engine": result.summary.engine, "exit_status": result.exit_status,
                           "clean": result.clean, "verdict": result.verdict, "rows": m.counts.steps_sent,
                           "missing": m.counts.missing, "heartbeat_losses": m.integrity.heartbeat.losses,
                           "bus_load_percent": m.bus_load.data_rate_percent}
    for node in TEMPERATURE_NODES:
        out[f"rmse_C_{node}"] = m.accuracy.rmse_C.get(node)
        out[f"rmse_reference_{node}"] = m.accuracy.rmse_reference.get(node)
        out[f"max_abs_can_minus_float32_C_{node}"] = m.agreement.max_abs_can_minus_float32_C.get(node)
    cycles, source = step_cycles(m)
    out["cycles"], out["cycles_source"] = cycles, source
    out["log"] = m.integrity.log
    if m.report:
        out["report"] = m.report
    if result.junit_xml is not None:
        out["junit_xml"] = str(result.junit_xml)
    for check in (result.acceptance.checks if result.acceptance else []):
        out[f"criterion_{check.name}"] = check.message
    return out


# ---------------------------------------------------------------- pytest hooks


def pytest_addoption(parser) -> None:
    group = parser.getgroup("thermal-bench", "the thermal bench (the thermal_bench fixture)")
    group.addoption("--bench-engine", choices=("python", "firmware"), default=None,
                    help="the engine of the target the bench starts (default python)")
    group.addoption("--bench-interface", default=None,
                    help="attach to the target already on this python-can interface (e.g. udp_multicast, socketcan)")
    group.addoption("--bench-channel", default=None, help="its channel (e.g. vcan0, a multicast group)")
    group.addoption("--bench-bitrate", type=int, default=None, help="its bit rate")
    group.addoption("--bench-bus-kwargs", action="append", default=[], metavar="KEY=VALUE",
                    help="more can.Bus keyword arguments, e.g. port=43113 (repeatable)")
    group.addoption("--bench-profile", default=None, metavar="FILE",
                    help="TOML profile: [target], [bus], [run] (see bench.pytest_plugin.load_profile)")
    group.addoption("--bench-out", default=None, metavar="DIR",
                    help="keep each test's logs, reports and JUnit XML under DIR (default: pytest's tmp_path)")


_CONFIG = pytest.StashKey[BenchConfig]()


def pytest_configure(config) -> None:
    config.addinivalue_line("markers", f"{MARKER}(*targets): run only against these bench targets: "
                                       "python, firmware (a target the bench starts), external (an attached one)")
    config.stash[_CONFIG] = config_of(config.option)   # a bad profile or option: a usage error, before collection


def bench_config(config) -> BenchConfig:
    """The session's BenchConfig (read in pytest_configure)."""
    return config.stash[_CONFIG]


def pytest_collection_modifyitems(config, items) -> None:
    marked = [item for item in items if item.get_closest_marker(MARKER) is not None]
    if not marked:
        return
    target = bench_config(config).target
    for item in marked:
        wanted = item.get_closest_marker(MARKER).args
        bad = [t for t in wanted if t not in TARGETS]
        if bad:
            raise pytest.UsageError(f"{item.nodeid}: @pytest.mark.{MARKER} names {bad[0]!r}; use "
                                    f"{', '.join(TARGETS)}")
        if target not in wanted:
            item.add_marker(pytest.mark.skip(reason=f"for the {', '.join(wanted)} target(s); this session's is "
                                                    f"{target}"))


def pytest_report_header(config) -> str | None:
    if not any(getattr(config.option, name, None) for name in ("bench_engine", "bench_interface", "bench_profile")):
        return None
    return f"thermal bench: {bench_config(config).describe()}"


def _recorder(request):
    """How a figure reaches pytest's JUnit XML: a property of the test (junit_family xunit1 or legacy), or under
    xunit2, whose schema has no properties in a testcase, a property of the suite named after the test."""
    if request.config.getini("junit_family") != "xunit2":
        return request.getfixturevalue("record_property")
    suite = request.getfixturevalue("record_testsuite_property")
    return lambda name, value: suite(f"{request.node.nodeid}::{name}", value)


@pytest.fixture
def thermal_bench(request, tmp_path) -> Iterator[ThermalBench]:
    """The bench against this session's target (--bench-engine, --bench-interface ..., --bench-profile)."""
    config = bench_config(request.config)
    record_property = _recorder(request)
    out = tmp_path
    if config.out_dir is not None:
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in request.node.nodeid)
        out = config.out_dir / safe
        out.mkdir(parents=True, exist_ok=True)
    bench = ThermalBench(config, out, record_property)
    record_property("bench_target", config.describe())
    started = time.perf_counter()
    yield bench
    record_property("bench_seconds", round(time.perf_counter() - started, 2))
