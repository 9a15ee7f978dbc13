import importlib.util
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


def _load_helpers():
    """tests/helpers.py as the module `helpers`, so any test or conftest can `from helpers import ...`.

    Not through sys.path: --import-mode=importlib adds nothing there, and putting tests/ there would let its
    directories without __init__.py (tests/bench, tests/dbc) shadow the real packages as namespace packages
    whenever the repository root itself is not on sys.path (`pytest` run from elsewhere)."""
    path = Path(__file__).resolve().with_name("helpers.py")
    loaded = sys.modules.get("helpers")
    if loaded is None or Path(getattr(loaded, "__file__", "") or "").resolve() != path:
        spec = importlib.util.spec_from_file_location("helpers", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules["helpers"] = module
        spec.loader.exec_module(module)
    return sys.modules["helpers"]


_load_helpers()

from helpers import (  # noqa: E402
    FirmwareBuilds,
    KernelCompile,
    artifact_text,
    built_observer,
    close_fork_server,
    private_udp_bus,
    run_shared_dir,
    start_kernel_compile,
    synthetic_columns,
    wait_for_kernels,
    write_synthetic_dataset,
)

KERNELS = pytest.StashKey[KernelCompile]()


@pytest.fixture
def udp_bus():
    """A udp_multicast bus no other test (or run) shares, on the machine-local group `auto` uses."""
    return private_udp_bus()


@pytest.fixture(scope="session")
def default_data_root(tmp_path_factory) -> Path:
    """Where the session's default datasets (`ensure_default_datasets`, ~5 s to generate) go: one directory for the
    whole run, so the drive and model suites and every pytest-xdist worker share one generation
    (`ensure_default_datasets` locks the directory while it generates; the others wait and reuse the files)."""
    return run_shared_dir(tmp_path_factory, "default-data")


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("data") / "small.csv", synthetic_columns(600),
                                   "synthetic test data")


@pytest.fixture(scope="session")
def artifacts(tmp_path_factory) -> dict[str, Path]:
    """lti (balanced), original (lti, the paper's polynomial realization), modal (lti), pv, hammerstein (a real
    sigmoid)."""
    kinds = {"lti": ("lti-lptn", "balanced"), "original": ("lti-lptn", "original"), "modal": ("lti-lptn", "modal"),
             "pv": ("pv-lptn", "physical"), "hammerstein": ("hammerstein", "balanced")}
    out = tmp_path_factory.mktemp("artifacts")
    paths = {}
    for name, (kind, realization) in kinds.items():
        paths[name] = out / f"{name}.json"
        paths[name].write_text(artifact_text(kind, realization), encoding="utf-8")
    return paths


@pytest.fixture(scope="session")
def firmware_builds(tmp_path_factory) -> FirmwareBuilds:
    """firmware_builds.build(generated, isr=False) -> the BuildResult of `toolchain.build_firmware`, built once per
    run for each distinct set of sources and shared by every pytest-xdist worker (`helpers.FirmwareBuilds`)."""
    return FirmwareBuilds(run_shared_dir(tmp_path_factory, "firmware-builds"))


@pytest.fixture(scope="session")
def firmware_elf(artifacts, firmware_builds) -> Callable[..., Path]:
    """firmware_elf(name of `artifacts` or an artifact path, isr=False) -> its firmware ELF: the packaged artifacts'
    shipped ELF without building (as `firmware_for`), any other (and with `isr` the timing image with the current
    loop's interrupt, always built) built once per run, in `firmware_builds`' cache."""
    built: dict[tuple[Path, bool], Path] = {}

    def get(which: str | Path, isr: bool = False) -> Path:
        from bench.firmware.codegen import generate
        from bench.firmware.images import packaged_elf
        from target_sim.artifact import load_artifact

        path = Path(artifacts[which]) if isinstance(which, str) and which in artifacts else Path(which)
        if (path, isr) not in built:
            artifact = load_artifact(path)
            shipped = None if isr else packaged_elf(artifact)
            built[path, isr] = shipped or firmware_builds.elf(generate(artifact), isr=isr)
        return built[path, isr]

    return get


def pytest_configure(config) -> None:
    """Run the suite with a terminal's signal dispositions. A suite started in the background (`cmd &`, nohup, some
    CI runners) inherits SIGINT and SIGHUP ignored, every command it starts inherits that, and the bench keeps an
    inherited ignore on purpose (`nohup bench run` must survive the hangup): the signal tests, which model a command
    started from a terminal, would then see their SIGINT and SIGHUP ignored. The nohup test sets its own ignore."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)


@pytest.fixture(scope="session")
def observer_artifact(tmp_path_factory, small_dataset) -> Path:
    """The packaged hammerstein model with an observer of its winding node (winding_C), written by `bench observer`
    on the small synthetic dataset with a two-run tuning (its Q and R are the search's start: what matters here is
    the protocol, not the tuning), without a bias state (the filter these protocol tests were written for)."""
    return built_observer(tmp_path_factory, small_dataset, "observer", "--bias", "none")


@pytest.fixture(scope="session")
def flux_observer_artifact(tmp_path_factory) -> tuple[Path, Path]:
    """(artifact, dataset): a model with an electrical loss model and an observer of two measurements, a stator NTC
    (25 s lag, +0.8 K offset) and the flux linkage from u_d, u_q, i_d, i_q and speed, written by `bench observer`
    with a two-run tuning on a synthetic dataset whose voltages follow the steady-state voltage equations of its
    magnet and winding temperatures (what matters here is the protocol, not the tuning)."""
    from bench.cli import main

    from helpers import electrical_artifact_text, flux_columns

    out = tmp_path_factory.mktemp("flux-observer")
    model = out / "electrical.json"
    model.write_text(electrical_artifact_text(), encoding="utf-8")
    data = write_synthetic_dataset(out / "flux.csv", flux_columns(600), "synthetic data with voltages and an NTC")
    artifact = out / "observer-ntc-flux.json"
    assert main(["observer", "--model", str(model), "--train", str(data), "--measure", "ntc_C", "--offset", "0.8",
                 "--lag", "25", "--flux", "--evaluations", "2", "--bias", "none", "--out", str(artifact),
                 "--quiet"]) == 0
    return artifact, data


@pytest.fixture(scope="session")
def resistance_observer_artifact(flux_observer_artifact, tmp_path_factory) -> tuple[Path, Path]:
    """(artifact, dataset): the flux linkage and the winding temperature from the stator resistance (both from u_d,
    u_q, i_d, i_q and speed; no sensor), written by `bench observer` on the flux observer's synthetic dataset with a
    two-run tuning (the protocol matters here, not the tuning)."""
    from bench.cli import main

    data = flux_observer_artifact[1]
    model = data.parent / "electrical.json"
    artifact = tmp_path_factory.mktemp("resistance-observer") / "observer-flux-resistance.json"
    assert main(["observer", "--model", str(model), "--train", str(data), "--measure", "none", "--flux",
                 "--resistance", "--evaluations", "2", "--out", str(artifact), "--quiet"]) == 0
    return artifact, data


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session) -> None:
    """A run on pytest-xdist workers (`-n`): before they start, begin compiling the numba kernels once, in the
    background (helpers.start_kernel_compile); a run in one process compiles them where it uses them."""
    if session.config.pluginmanager.has_plugin("dsession"):
        session.config.stash[KERNELS] = start_kernel_compile()


def pytest_collection_finish(session) -> None:
    """A worker, its tests collected, waits for the kernels before its first test (helpers.wait_for_kernels)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        wait_for_kernels()


def pytest_terminal_summary(terminalreporter, config) -> None:
    """A warm-up that failed says so (the workers compiled the kernels themselves: slower, nothing else)."""
    if KERNELS in config.stash:
        for sentence in config.stash[KERNELS].failures():
            terminalreporter.write_line(sentence, yellow=True)


def pytest_unconfigure(config) -> None:
    close_fork_server()      # run_cli's (helpers.fork_server), in each process that used it
    if KERNELS in config.stash:
        config.stash[KERNELS].close()
