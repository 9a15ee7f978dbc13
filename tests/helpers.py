"""What the test directories share: the repository root, synthetic drive data, small model artifacts, a private
udp_multicast bus, a runner for the command-line entry points in a child process, the frames of a lockstep
session with an in-process target (to tamper with, as the log-analysis tests do), and the numba kernels compiled
once for a run on pytest-xdist workers.

The tests run with `--import-mode=importlib`, which puts nothing on sys.path; tests/conftest.py loads this file
as the module `helpers` (see there why not through sys.path), so any test module or conftest can
`from helpers import ...`.
"""

from __future__ import annotations

import fcntl
import os
import struct
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import can

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------- data


def synthetic_columns(rows: int, seed: int = 5, *, torque_sd: float = 15.0, torque_offset: float = 0.0,
                      torque_max: float = 600.0, speed_sd: float = 80.0, speed_offset: float = 0.0,
                      coolant_amplitude: float = 2.0, coolant_period: float = 60.0, ambient_period: float = 90.0,
                      linear_warming: bool = False) -> dict[str, np.ndarray]:
    """A drive-like dataset at 5 Hz, values at the CAN resolution: torque and speed random walks (clipped to
    -600..`torque_max` Nm and 0..9000 rpm), slow sinusoidal coolant and ambient drift (periods in units of
    2π seconds), winding and rotor surface warming from 40 °C (exponentially, or linearly with
    `linear_warming`), PM = surface + 5 °C."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 0.2
    torque = np.round(np.clip(np.cumsum(rng.normal(0, torque_sd, rows)) + torque_offset, -600, torque_max), 1)
    speed = np.round(np.clip(np.abs(np.cumsum(rng.normal(0, speed_sd, rows))) + speed_offset, 0, 9000), 0)
    coolant = np.round(40 + coolant_amplitude * np.sin(t / coolant_period), 1)
    ambient = np.round(25 + 0.5 * np.sin(t / ambient_period), 1)
    if linear_warming:
        winding = np.round(40 + 0.05 * t, 1)
        surface = np.round(40 + 0.02 * t, 1)
    else:
        winding = np.round(40 + 30 * (1 - np.exp(-t / 300.0)), 1)
        surface = np.round(40 + 10 * (1 - np.exp(-t / 900.0)), 1)
    return {"time_s": t, "torque_Nm": torque, "speed_rpm": speed, "coolant_C": coolant, "ambient_C": ambient,
            "winding_C": winding, "rotor_surface_C": surface, "pm_C": np.round(surface + 5.0, 1)}


def write_synthetic_dataset(path: Path, columns: dict[str, np.ndarray], note: str) -> Path:
    """`columns` as a dataset file with its sidecar (coolant set point 40 °C); returns `path`."""
    from bench.drive.dataset import write_dataset

    write_dataset(path, columns, {"coolant_setpoint_C": 40.0, "note": note})
    return path


# ---------------------------------------------------------------- models


def model_spec(kind: str = "hammerstein", realization: str = "balanced"):
    """A ModelSpec of the packaged parameters at Δt = 0.5 s with nominal maps: pv-lptn (euler, physical), or
    lti-lptn / hammerstein (zoh, `realization`); the Hammerstein model with a real (non-identity) sigmoid."""
    from bench.drive.motor import VIRTUAL_MOTOR, nominal_loss_maps
    from bench.model.builder import ModelSpec, SigmoidInputs
    from bench.thermal.parameters import TABLE1_REFINED

    maps = nominal_loss_maps()
    if kind == "pv-lptn":
        return ModelSpec("pv-lptn", TABLE1_REFINED, 0.5, "euler", "physical", maps, VIRTUAL_MOTOR)
    sigmoid = None
    if kind == "hammerstein":
        sigmoid = SigmoidInputs.from_vector([900.0, 3000.0, 700.0, 120.0],
                                            np.r_[np.full(4, 2.0), np.zeros(4), np.full(4, 0.3), np.full(4, 0.8),
                                                  np.zeros(4)])
    return ModelSpec(kind, TABLE1_REFINED, 0.5, "zoh", realization, maps, VIRTUAL_MOTOR, sigmoid=sigmoid)


def artifact_text(kind: str = "hammerstein", realization: str = "balanced") -> str:
    """The model artifact of `model_spec(kind, realization)` as JSON text."""
    from bench.model.builder import build_artifact
    from target_sim.artifact import dumps

    return dumps(build_artifact(model_spec(kind, realization)))


# ---------------------------------------------------------------- processes and buses


def subprocess_env(*, can_settings: bool = True, **extra: str) -> dict[str, str]:
    """The environment of a child process: this one's, with the Agg backend and unbuffered output; without the
    developer's python-can settings (CAN_INTERFACE, CAN_CHANNEL, ...) unless `can_settings`; then `extra`."""
    env = {k: v for k, v in os.environ.items() if can_settings or not k.startswith("CAN_")}
    env.update(MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    env.update(extra)
    return env


def wait_for(predicate, timeout: float, poll_s: float = 0.05) -> bool:
    """Poll `predicate` until it holds or `timeout` seconds passed; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return bool(predicate())


def alive(pid: int) -> bool:
    """Process `pid` exists and is not a zombie (one waiting for its adopter to reap it has ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def processes_of(marker: str, exclude: tuple[int, ...] = ()) -> dict[int, str]:
    """Live processes (not this one) whose command line holds `marker`: pid -> command line, words joined by
    spaces (from /proc/*/cmdline)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) in (os.getpid(), *exclude):
            continue
        try:
            argv = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if marker in argv and alive(int(entry.name)):
            found[int(entry.name)] = argv
    return found


class TiedProcess:
    """`python ARGV...` (e.g. "-m", "target_sim", ...) that dies with this test process: started through
    `python -m dbc.lifeline` (`dbc.lifeline.tied_command`), which arms Linux's parent-death signal (SIGTERM) in the
    child and then becomes the command, so a pytest killed in the middle of a test (SIGKILL, a CI job cancelled)
    leaves no process behind. Start it from the thread that lives as long as it does (a test's or fixture's, not a
    helper thread): the kernel's signal fires when that thread ends.

    A context manager: `stop()` (SIGTERM, then the exit it reports; SIGKILL after `stop_timeout` s) when the block
    ends, whatever ended it; `stdout`/`stderr` then hold what it wrote to a PIPE (None otherwise). `env` defaults to
    `subprocess_env()`; `popen` goes to subprocess.Popen (stdin, stdout, stderr, text, start_new_session...)."""

    def __init__(self, *argv: str, cwd: Path | str | None = None, env: dict[str, str] | None = None,
                 stop_timeout: float = 60.0, **popen) -> None:
        from dbc.lifeline import tied_command, tied_environment

        self.stop_timeout = stop_timeout
        self.stdout: str | bytes | None = None
        self.stderr: str | bytes | None = None
        self.process = subprocess.Popen(tied_command([sys.executable, *map(str, argv)]), cwd=cwd or ROOT,
                                        env=tied_environment(subprocess_env() if env is None else env), **popen)

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def returncode(self) -> int | None:
        return self.process.returncode

    def poll(self) -> int | None:
        return self.process.poll()

    def stop(self) -> int:
        """SIGTERM (if it still runs), then wait for its exit (generous: a busy machine), collecting its piped
        output; SIGKILL if it has not exited after `stop_timeout` s. Its exit status; again: the same."""
        if self.process.returncode is None:
            if self.process.poll() is None:
                self.process.terminate()
            try:
                self.stdout, self.stderr = self.process.communicate(timeout=self.stop_timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.stdout, self.stderr = self.process.communicate()
        return self.process.returncode

    def __enter__(self) -> TiedProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def start_target(*args: str, **kwargs) -> TiedProcess:
    """`python -m target_sim ARGS...` as a `TiedProcess` (keyword arguments: its)."""
    return TiedProcess("-m", "target_sim", *args, **kwargs)


# run_cli's `-m bench` and `-m target_sim` as plain subprocesses (`sys.executable -m ...`), not forked, when "1"
SUBPROCESS_ENV = "BENCH_TESTS_SUBPROCESS"
FORKED_MODULES = ("bench", "target_sim")


def run_cli(*argv: str, cwd: Path | None = None, timeout: float = 180,
            can_settings: bool = True) -> subprocess.CompletedProcess:
    """`python ARGV...` (e.g. "-m", "bench", "run", ...) in the repository root by default, output captured.

    `-m bench` and `-m target_sim` are forked from this process's fork server (`fork_server`: the same command in
    a fresh interpreter, without its 2.5 CPU-s of imports) unless BENCH_TESTS_SUBPROCESS=1; anything else, and
    everything then, runs as `sys.executable ARGV...`. A timeout raises subprocess.TimeoutExpired either way."""
    command = [sys.executable, *argv]
    env = subprocess_env(can_settings=can_settings)
    if argv[:1] == ("-m",) and argv[1:2] and argv[1] in FORKED_MODULES and os.environ.get(SUBPROCESS_ENV) != "1":
        done = fork_server().run(argv[1], list(argv[2:]), cwd=cwd or ROOT, env=env, timeout=timeout)
        if done.timed_out:
            raise subprocess.TimeoutExpired(command, timeout, done.stdout, done.stderr)
        return subprocess.CompletedProcess(command, done.rc, done.stdout, done.stderr)
    return subprocess.run(command, cwd=cwd or ROOT, env=env, capture_output=True, text=True, timeout=timeout)


# ---------------------------------------------------------------- the fork server (tests/zygote.py)

ZYGOTE = Path(__file__).with_name("zygote.py")


@dataclass
class Forked:
    """What a forked command did: its exit status, its output, its wall time, and whether it was stopped at its
    timeout (then killed with its process group)."""

    rc: int
    stdout: str
    stderr: str
    seconds: float
    timed_out: bool


class ForkServer:
    """`python -m MODULE ARGS` as a child forked from a server that imported the CLIs' modules once
    (tests/zygote.py, started with `env`): a fresh interpreter that never ran pytest, in its own session, with its
    own cwd and environment; about 0.1 s of start-up where a new interpreter spends 2.5 CPU-s importing. One
    command at a time (the server waits for each child); the server is restarted if it died."""

    def __init__(self, workdir: Path, env: dict[str, str]):
        self.workdir = Path(workdir)
        self.env = env
        self._lock = threading.Lock()
        self._server: subprocess.Popen | None = None
        self._count = 0

    def _started(self) -> subprocess.Popen:
        if self._server is None or self._server.poll() is not None:
            with (self.workdir / "zygote.stderr").open("ab") as log:
                self._server = subprocess.Popen([sys.executable, str(ZYGOTE)], cwd=ROOT, env=self.env,
                                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, text=True,
                                                bufsize=1)
        return self._server

    def run(self, module: str, args: list[str], *, cwd: Path, env: dict[str, str], timeout: float) -> Forked:
        """Run `python -m MODULE ARGS` in `cwd` with exactly the environment `env`; RuntimeError if the server
        died (its stderr is in the work directory)."""
        import json

        with self._lock:
            self._count += 1
            stdout = self.workdir / f"run{self._count}.stdout"
            stderr = self.workdir / f"run{self._count}.stderr"
            server = self._started()
            request = {"module": module, "args": [str(a) for a in args], "cwd": str(cwd), "timeout": timeout,
                       "env": env, "stdout": str(stdout), "stderr": str(stderr)}
            server.stdin.write(json.dumps(request) + "\n")
            server.stdin.flush()
            reply = server.stdout.readline()
            if not reply:
                raise RuntimeError(f"the fork server died; see {self.workdir / 'zygote.stderr'}")
            reply = json.loads(reply)
        done = Forked(reply["rc"], stdout.read_text(errors="replace"), stderr.read_text(errors="replace"),
                      reply["seconds"], reply["timed_out"])
        stdout.unlink(missing_ok=True)
        stderr.unlink(missing_ok=True)
        return done

    def close(self) -> None:
        """End the server (EOF on its stdin; killed after 10 s)."""
        if self._server is not None:
            self._server.stdin.close()
            try:
                self._server.wait(10)
            except subprocess.TimeoutExpired:
                self._server.kill()
                self._server.wait()
            self._server = None


_FORK_SERVER: ForkServer | None = None


def fork_server() -> ForkServer:
    """This process's fork server for `run_cli`, started at its first use (tests/conftest.py closes it)."""
    global _FORK_SERVER
    if _FORK_SERVER is None:
        _FORK_SERVER = ForkServer(Path(tempfile.mkdtemp(prefix="bench-tests-fork-")), subprocess_env())
    return _FORK_SERVER


def close_fork_server() -> None:
    """End `fork_server`'s server and remove its work directory (kept when the server wrote to its stderr)."""
    global _FORK_SERVER
    if _FORK_SERVER is not None:
        import shutil

        _FORK_SERVER.close()
        log = _FORK_SERVER.workdir / "zygote.stderr"
        if not (log.is_file() and log.stat().st_size):
            shutil.rmtree(_FORK_SERVER.workdir, ignore_errors=True)
        _FORK_SERVER = None


def private_udp_bus():
    """A udp_multicast bus no other test (or run) shares, on the machine-local group `auto` uses."""
    from dbc.transport import BusConfig, resolve

    return resolve(BusConfig("udp_multicast"), session_unique=True)


# ---------------------------------------------------------------- numba kernels, compiled once for the workers

# the lock the workers wait on while the kernels compile (its path; set in the controller for the workers)
KERNELS_LOCK_ENV = "BENCH_TESTS_KERNELS_LOCK"


@dataclass
class KernelCompile:
    """The children compiling the kernels (one per module of `bench.thermal.kernels`) and their shared log."""

    lock: Path
    log: Path
    children: list[subprocess.Popen]

    def failures(self) -> list[str]:
        """A sentence per child that exited with a failure (the workers then compiled the kernels themselves)."""
        return [f"the numba kernel warm-up `python -m {' '.join(child.args[4:])}` exited {child.returncode} (see "
                f"{self.log}); the workers compiled the kernels themselves" for child in self.children
                if child.poll() not in (None, 0)]

    def close(self) -> None:
        """Stop the children still compiling (a short run; numba writes its cache files whole, so a stopped
        compile leaves none half-written) and remove the lock, and the log unless a child failed."""
        for child in self.children:
            if child.poll() is None:
                child.terminate()
                child.wait()
        self.lock.unlink(missing_ok=True)
        if all(child.returncode in (0, -15) for child in self.children):
            self.log.unlink(missing_ok=True)


def start_kernel_compile() -> KernelCompile:
    """Start compiling every numba kernel into numba's on-disk cache, one child process per module of
    `bench.thermal.kernels`, and return at once. The children hold an exclusive lock on a new file (named in
    `KERNELS_LOCK_ENV` from now on) until they exit, however they exit; `wait_for_kernels` waits for it.

    Why: with a cold cache (a fresh clone) each pytest-xdist worker, and each `python -m bench` a test starts
    before the cache is written, compiled the same kernels (about 45 CPU-s each). Compiled once here, while the
    workers start and collect, the workers and their subprocesses load them (about 1 s)."""
    from bench.thermal.kernels import KERNEL_MODULES

    fd, name = tempfile.mkstemp(prefix="bench-kernels-", suffix=".lock")
    lock, log = Path(name), Path(name).with_suffix(".log")
    fcntl.flock(fd, fcntl.LOCK_EX)
    children = []
    try:
        with log.open("w") as out:
            for module in KERNEL_MODULES:     # in parallel: the slowest module (kalman) takes half of the whole
                children.append(subprocess.Popen([sys.executable, "-W", "ignore", "-m", "bench.thermal.kernels",
                                                  module], cwd=ROOT, env=subprocess_env(), pass_fds=(fd,),
                                                 stdin=subprocess.DEVNULL, stdout=out, stderr=out))
    finally:
        os.close(fd)     # the lock stays held while a child holds the file open
    os.environ[KERNELS_LOCK_ENV] = str(lock)
    return KernelCompile(lock, log, children)


def wait_for_kernels(timeout: float = 600.0) -> bool:
    """Wait until the kernels `start_kernel_compile` compiles are in the cache (True), or `timeout` s (False:
    the caller compiles what it needs itself, as without the warm-up). Nothing to wait for: True."""
    path = os.environ.get(KERNELS_LOCK_ENV)
    try:
        fd = os.open(path, os.O_RDONLY) if path else None
    except OSError:
        return True
    if fd is None:
        return True
    deadline = time.monotonic() + timeout
    try:
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
                return True
            except BlockingIOError:
                if time.monotonic() > deadline:
                    return False
                time.sleep(0.1)
    finally:
        os.close(fd)


# ---------------------------------------------------------------- observers


def built_observer(tmp_path_factory, dataset: Path, name: str, *options: str) -> Path:
    """`bench observer` on `dataset` with a two-run tuning (the protocol matters here, not the tuning) and `options`,
    written as NAME.json into a fresh directory of its own."""
    from bench.cli import main

    out = tmp_path_factory.mktemp(f"observer-{name}") / f"{name}.json"
    assert main(["observer", "--train", str(dataset), "--evaluations", "2", *options, "--out", str(out),
                 "--quiet"]) == 0
    return out


def observer_in_form(path: Path, form: str, out: Path) -> Path:
    """The observer artifact at `path` deploying the covariance form `form` instead, written to `out`."""
    from bench.observer.section import with_observer
    from target_sim.artifact import dumps, load_artifact

    artifact = load_artifact(path)
    out.write_text(dumps(with_observer(artifact, {**artifact.content["observer"], "form": form})), encoding="utf-8")
    return out


def steady_form(path: Path, tmp_path_factory) -> Path:
    """The observer artifact at `path` in the steady-state-gain form (the K_ss rows the artifact stores)."""
    return observer_in_form(path, "steady", tmp_path_factory.mktemp("observer-steady") / "steady.json")


# ---------------------------------------------------------------- firmware


def run_shared_dir(tmp_path_factory, name: str) -> Path:
    """A directory every pytest-xdist worker of this run shares (beside the workers' own temporary directories, in
    the run's), or this session's own in a run in one process. Not created under xdist: its first user makes it."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return tmp_path_factory.getbasetemp().parent / name
    return tmp_path_factory.mktemp(name)


class FirmwareBuilds:
    """`toolchain.build_firmware`, once per run for each distinct build: a build's ELF and map are kept in a
    directory all the run's workers share, under the sha256 of everything the compiler and linker read (every
    source file, the flags, the compiler command and its version). Why: the firmware tests of different modules
    (on different workers) build the same C, and a build costs about 1 CPU-s of compiling (node.c most of it).

    Two workers that build the same sources at once both build (the builds are deterministic: byte for byte the
    same) and each writes under a temporary name, then renames, so a reader sees a whole ELF and map or none."""

    def __init__(self, directory: Path):
        self.directory = Path(directory)

    def key(self, sources: dict[str, str], isr: bool) -> str:
        import hashlib
        import json

        from bench.firmware import toolchain

        what = {"sources": sources, "compile": toolchain.compile_flags(Path("."), isr=isr),
                "link": list(toolchain.LINK_FLAGS), "compiler": list(toolchain.COMPILER),
                "version": toolchain.toolchain_version()}
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()

    def build(self, generated, *, isr: bool = False):
        """The BuildResult of `build_firmware(generated, isr=isr)`: built now, or read back from this run's cache."""
        from bench.firmware import toolchain
        from target_sim.firmware import memory_from_elf

        sources = toolchain.firmware_sources(generated, isr=isr)
        elf, map_text = self._paths(sources, isr)
        if elf.is_file() and map_text.is_file():
            payload = elf.read_bytes()
            return toolchain.BuildResult(elf=payload, map_text=map_text.read_text(encoding="utf-8"), sources=sources,
                                         memory=memory_from_elf(payload), toolchain=toolchain.toolchain_version())
        return self._build(generated, isr, elf, map_text)

    def elf(self, generated, *, isr: bool = False) -> Path:
        """The path of the ELF `build_firmware(generated, isr=isr)` gives, in this run's cache (built if not there)."""
        from bench.firmware import toolchain

        elf, map_text = self._paths(toolchain.firmware_sources(generated, isr=isr), isr)
        if not (elf.is_file() and map_text.is_file()):
            self._build(generated, isr, elf, map_text)
        return elf

    def _paths(self, sources: dict[str, str], isr: bool) -> tuple[Path, Path]:
        key = self.key(sources, isr)
        return self.directory / f"{key}.elf", self.directory / f"{key}.map"

    @staticmethod
    def _build(generated, isr: bool, elf: Path, map_text: Path):
        from bench.fileio import write_bytes_atomically
        from bench.firmware import toolchain

        result = toolchain.build_firmware(generated, isr=isr)
        # each written under a temporary name, then renamed; the map first: the ELF marks a whole entry
        write_bytes_atomically(map_text, result.map_text.encode("utf-8"))
        write_bytes_atomically(elf, result.elf)
        return result


def patched_elf(path: Path, symbol: str, data: bytes, offset: int = 0) -> bytes:
    """The ELF's bytes with `data` written over `symbol` (+ `offset`) in its file image: a firmware that loads
    like the original and computes or faults differently (e.g. b"\\xfe\\xde", a Thumb UDF, at a function's entry)."""
    from elftools.elf.elffile import ELFFile

    image = bytearray(Path(path).read_bytes())
    with Path(path).open("rb") as handle:
        elf = ELFFile(handle)
        address = (elf.get_section_by_name(".symtab").get_symbol_by_name(symbol)[0]["st_value"] & ~1) + offset
        section = next(s for s in elf.iter_sections()
                       if s["sh_addr"] <= address < s["sh_addr"] + s["sh_size"] and s["sh_type"] != "SHT_NOBITS")
        at = section["sh_offset"] + address - section["sh_addr"]
    image[at:at + len(data)] = data
    return bytes(image)


# ---------------------------------------------------------------- electrical loss model (d/q currents)

# The coefficients of a plausible electrical loss model of the virtual 200 kW motor (losses from the d/q currents and
# the speed, target_sim.model.ElectricalLosses), for artifacts built without the identification.
ELECTRICAL_TEST_COEFFICIENTS = {
    "pole_pairs": 10.0, "stator_resistance_ohm": 0.008, "ac_factor": 0.3, "ac_reference_Hz": 1000.0,
    "iron_hysteresis_W": 600.0, "iron_eddy_W": 900.0, "iron_reference_Hz": 1000.0, "iron_current_factor": 0.3,
    "magnet_W": 150.0, "magnet_reference_Hz": 1000.0, "magnet_no_load_share": 0.4}


def electrical_artifact_text(base: str | Path | None = None) -> str:
    """A schema-2 artifact with an electrical loss model (`losses.model` "electrical"): the packaged Hammerstein
    artifact (or the artifact file `base`) with its loss maps replaced by ELECTRICAL_TEST_COEFFICIENTS, resealed."""
    import json

    from target_sim.artifact import dumps, encode_array
    from target_sim.losses.electrical import COEFFICIENTS as ELECTRICAL_COEFFICIENTS

    path = Path(base) if base is not None else ROOT / "bench" / "data" / "default_model.json"
    content = json.loads(path.read_text(encoding="utf-8"))
    content.pop("sha256", None)
    content["losses"] = {"model": "electrical", "current_max_A": encode_array(400.0),
                         "alpha_cu_per_K": encode_array(0.0039), "copper_reference_C": encode_array(20.0),
                         **{k: encode_array(ELECTRICAL_TEST_COEFFICIENTS[k]) for k in ELECTRICAL_COEFFICIENTS}}
    content["schema_version"] = 2
    return dumps(content)


def with_currents(columns: dict[str, np.ndarray], seed: int = 7) -> dict[str, np.ndarray]:
    """`columns` plus d/q current columns at the CAN resolution (0.1 A) that follow the torque: i_q about
    torque / 1.5 A/Nm, i_d field weakening with the speed, a little noise; within ±3000 A."""
    rng = np.random.default_rng(seed)
    torque, speed = columns["torque_Nm"], columns["speed_rpm"]
    i_q = np.round(np.clip(torque / 1.5 + rng.normal(0, 2.0, torque.size), -2900, 2900), 1)
    i_d = np.round(np.clip(-0.04 * np.abs(speed) - 0.2 * np.abs(i_q) + rng.normal(0, 2.0, torque.size), -2900, 0),
                   1)
    return {**columns, "i_d_A": i_d, "i_q_A": i_q}


def example_results(**changes):
    """A `RunResults` with plausible figures (every field set), for tests of what reads them."""
    from dataclasses import replace

    from bench.analysis.results import (
        Accuracy,
        Agreement,
        BusLoad,
        CycleFigures,
        FigureRows,
        Heartbeat,
        Integrity,
        MeasuredRmse,
        Memory,
        ModelInfo,
        NodeLabels,
        NodeValues,
        NonFinite,
        Percentiles,
        Replies,
        RunResults,
        Throughput,
        Timing,
    )

    results = RunResults(
        model=ModelInfo("b783e4e4", "hammerstein", "balanced", 1.0, "maps", "b783e4e4"),
        counts=Replies(300, 300, 0, 0, 60),
        agreement=Agreement(NodeValues(0.001, 0.0049, 0.002, 0.003), True, 300, "offline float32", 0,
                            NodeValues(0.0, 0.0, 0.0, 0.0), 1, 0),
        accuracy=Accuracy(NodeValues(1e-5, 2e-5, 3e-5, 4e-5), NonFinite(0, 0), NodeValues(1.0, 0.5, 2.0, 0.25),
                          NodeLabels("float64 model", "measured", "float64 model", "measured"),
                          {"float64": MeasuredRmse(0.4, 0.2), "float32": MeasuredRmse(0.4, 0.2)}),
        timing=Timing(Percentiles(101.5, 180.0, 331.0), 0, 1989, 22.1, 2.2, "firmware", CycleFigures(1403, 1410),
                      CycleFigures(15.6, 15.7), 90.0),
        memory=Memory(4096, 1024, "firmware ELF", 5000, 1200),
        throughput=Throughput(Percentiles(400.0, 900.0, 1200.0), 0.3, 1083.0, 216.0),
        integrity=Integrity(Heartbeat(3, 0.1, 0), {"crc": 0}, {}, {}, {}, 0, [], 1500, True, True, False, 299,
                            "/x/bench.blf"),
        faults=None,
        bus_load=BusLoad(500000, 130.5, 1.2, 1.0, [0.0, 1.0], [10.0, 12.5], 12.5),
        figure_rows=FigureRows(300, 300, 0, {}), notes=[], null_values={})
    return replace(results, **changes)


def example_summary(clean: bool = True, **changes):
    """A `RunSummary` of `example_results()`, as `bench run --json` gives it."""
    from dataclasses import replace

    from bench.analysis.results import BusInfo, RunSummary

    summary = RunSummary(engine="firmware", firmware=None, bus=BusInfo("udp_multicast", "ff11::1", 40000),
                         problems=[] if clean else ["3 of 300 rows got no reply"], clean=clean, faults=None,
                         host={"mode": "lockstep", "rows": 300}, metrics=example_results(), elapsed_s=8.5)
    return replace(summary, **changes)


# ---------------------------------------------------------------- logs of a lockstep session (in-process target)


SESSION_INITIAL = [40.0, 45.0, 41.0, 50.0]   # yoke, winding, tooth, magnet of session_frames' RESET


def session_drive(n: int, seed: int) -> np.ndarray:
    """`n` random drive rows (torque, speed, coolant 40 °C, ambient 25 °C)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([np.round(rng.uniform(0, 500, n), 1), np.round(rng.uniform(500, 8000, n)),
                            np.full(n, 40.0), np.full(n, 25.0)])


def session_start(codec) -> list:
    """The host's frames that start a session at SESSION_INITIAL: both ResetTemps, RESET, START."""
    from dbc import Command

    yoke, winding, tooth, magnet = SESSION_INITIAL
    return [codec.encode("ResetTemps1", {"Step": 0, "WindingTempInit": winding, "MagnetTempInit": magnet}),
            codec.encode("ResetTemps2", {"Step": 0, "YokeTempInit": yoke, "ToothTempInit": tooth}),
            codec.encode("Control", {"Command": int(Command.RESET), "Step": 0}),
            codec.encode("Control", {"Command": int(Command.START), "Step": 0})]


def session_frames(artifact, values: np.ndarray, *, stop: bool = True,
                   measurements: np.ndarray | None = None) -> list[can.Message]:
    """Every frame of a lockstep session as the host logs it (a Python target node answering in-process): the
    target's heartbeat before and during it, RESET and START, the rows (each after its Measurements frame with
    `measurements`, one row per data row), STOP (with `stop`)."""
    from dbc import Command, FrameCodec
    from host.replay import encode_row
    from target_sim.node import TargetNode

    node, host = TargetNode(artifact, clock_ns=lambda: 0), FrameCodec("HOST")
    frames = list(node.startup_frames())

    def send(messages):
        for message in messages:
            frames.append(message)
            frames.extend(node.handle(message))

    send(session_start(host))
    for row, value in enumerate(values):
        send(encode_row(host, row, value, None if measurements is None else measurements[row].tolist()))
        if row % 25 == 0:
            frames.extend(node.heartbeat_frames())
    if stop:
        send([host.encode("Control", {"Command": int(Command.STOP), "Step": 0})])
        frames.extend(node.heartbeat_frames())
    return frames


def xcp_download(address: int, value: float) -> list[can.Message]:
    """A calibration master's CONNECT, SET_MTA and DOWNLOAD of one float32 `value` at `address`."""
    import can

    from dbc.xcp import cmd_id
    from target_sim.xcp.codes import Cmd

    def xcp(data: bytes) -> can.Message:
        return can.Message(arbitration_id=cmd_id(), is_extended_id=False, data=data)
    return [xcp(bytes((Cmd.CONNECT, 0))), xcp(bytes((Cmd.SET_MTA, 0, 0, 0)) + struct.pack("<I", address)),
            xcp(bytes((Cmd.DOWNLOAD, 4)) + struct.pack("<f", value))]


def calibrated_session(node, rows: int, calibrate_after: int, cell: str | None, value: float, address: int = 0,
                       measured: np.ndarray | None = None) -> list[can.Message]:
    """Every frame of a lockstep session of `rows` rows with `node` (a Python or firmware target node, in-process:
    its startup frames and heartbeats too), and the DOWNLOAD of `value` into `cell` at `address` (None: no
    calibration) after row `calibrate_after`; every XCP reply positive."""
    from dbc import Command, FrameCodec
    from dbc.xcp import res_id
    from host.replay import encode_row

    host = FrameCodec("HOST")
    frames = list(node.startup_frames())

    def send(messages):
        for message in messages:
            frames.append(message)
            replies = node.handle(message)
            assert all(r.data[0] == 0xFF for r in replies if r.arbitration_id == res_id()), message
            frames.extend(replies)

    send(session_start(host))
    drive = session_drive(rows, 11)
    for row in range(rows):
        send(encode_row(host, row, drive[row], None if measured is None else measured[row].tolist()))
        if cell and row == calibrate_after:
            send(xcp_download(address, value))
        if row % 25 == 0:
            frames.extend(node.heartbeat_frames())
    send([host.encode("Control", {"Command": int(Command.STOP), "Step": 0})])
    frames.extend(node.heartbeat_frames())
    return frames


def write_frames(path, frames: list[can.Message]):
    """`frames` written to the log `path` (format by suffix), 0.1 ms apart."""
    from host.canlog import FrameLog

    log = FrameLog(path)
    for i, frame in enumerate(frames):
        frame.timestamp = 1000.0 + i * 1e-4
        log.write(frame)
    log.close()
    return path


def genuine_temps(artifact, values: np.ndarray) -> np.ndarray:
    """Each row's reply of a clean session, decoded from its frames."""
    from dbc.codec import decode_any
    from dbc.database import frame_id

    out = np.full((len(values), 4), np.nan)
    for frame in session_frames(artifact, values):
        if frame.arbitration_id in (frame_id("Temperatures1"), frame_id("Temperatures2")):
            decoded = decode_any(frame)
            for signal, index in {"Temperatures1": (("WindingTemp", 1), ("MagnetTemp", 3)),
                                  "Temperatures2": (("YokeTemp", 0), ("ToothTemp", 2))}[decoded.name]:
                out[int(decoded.signals["Step"]), index] = decoded.signals[signal]
    return out


def replies_by_row(frames: list[can.Message]) -> dict[int, list[can.Message]]:
    """The target's reply frames (Temperatures1, Temperatures2) of each row, by the Step they carry."""
    from dbc.codec import decode_any
    from dbc.database import frame_id

    ids = (frame_id("Temperatures1"), frame_id("Temperatures2"))
    out: dict[int, list[can.Message]] = {}
    for frame in frames:
        if frame.arbitration_id in ids:
            out.setdefault(int(decode_any(frame).signals["Step"]), []).append(frame)
    return out


def after_row(frames: list[can.Message], row: int, which: str = "reply") -> int:
    """Index in `frames` right after row `row`'s DriveTemps (which="drive") or its Temperatures2 ("reply")."""
    from dbc.codec import decode_any
    from dbc.database import frame_id

    fid, wanted = (frame_id("DriveTemps"), row) if which == "drive" else (frame_id("Temperatures2"), row)
    for i, frame in enumerate(frames):
        if frame.arbitration_id == fid and int(decode_any(frame).signals["Step"]) == wanted:
            return i + 1
    raise AssertionError(f"row {row} not found")


# the synthetic machine of `flux_columns`: ψ_0 (Vs) at 20 °C, α_B (1/K), L_d, L_q (H), R_s (Ω) at 20 °C, α_cu
FLUX_MACHINE = {"psi_0": 0.02, "alpha_B": -0.0011, "L_d": 2e-5, "L_q": 4e-5, "R_s": 0.008, "alpha_cu": 0.0039}


def flux_columns(rows: int, seed: int = 5) -> dict[str, np.ndarray]:
    """`synthetic_columns` at 1000-7000 rpm with d/q currents, the d/q voltages of the steady-state voltage
    equations at its magnet and winding temperatures (FLUX_MACHINE, the electrical test artifact's 10 pole pairs,
    0.1 V steps) and a stator NTC column (the winding through a 25 s lag, read 0.8 K high)."""
    columns = with_currents(synthetic_columns(rows, seed, speed_sd=60.0, speed_offset=1000.0, torque_max=300.0))
    columns["speed_rpm"] = np.clip(columns["speed_rpm"], 0.0, 7000.0)
    m = FLUX_MACHINE
    omega = ELECTRICAL_TEST_COEFFICIENTS["pole_pairs"] * 2 * np.pi / 60 * columns["speed_rpm"]
    r_s = m["R_s"] * (1 + m["alpha_cu"] * (columns["winding_C"] - 20.0))
    psi = m["psi_0"] * (1 + m["alpha_B"] * (columns["pm_C"] - 20.0))
    i_d, i_q = columns["i_d_A"], columns["i_q_A"]
    columns["u_d_V"] = np.round(r_s * i_d - omega * m["L_q"] * i_q, 1)
    columns["u_q_V"] = np.round(r_s * i_q + omega * (psi + m["L_d"] * i_d), 1)
    lag = np.exp(-0.2 / 25.0)
    ntc = np.empty(rows)
    ntc[0] = columns["winding_C"][0]
    for k in range(1, rows):
        ntc[k] = lag * ntc[k - 1] + (1 - lag) * columns["winding_C"][k]
    columns["ntc_C"] = np.round(ntc + 0.8, 1)
    return columns


def refused_in_one_sentence(capsys, argv: list[str]) -> str:
    """`bench ARGV` in this process: exit 1 with one sentence on stderr and nothing on stdout; that sentence."""
    from bench.cli import main

    assert main(argv) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("bench: error: ") and err.count("\n") == 1
    return err


# ---------------------------------------------------------------- campaigns on a Dask cluster


def assert_table_equals_files(out: Path) -> None:
    """Issue 39: a campaign directory's table equals its files. Every done row names its attempt's directory, whose
    summary.json is the row's summary and whose log's sha256 is the row's log_sha256; every row's directory exists,
    and OUT/runs holds no directory that no row names."""
    import hashlib
    import json
    import sqlite3

    with sqlite3.connect(out / "campaign.sqlite") as db:
        db.row_factory = sqlite3.Row
        rows = [dict(r) for r in db.execute("SELECT * FROM runs")]
    named = set()
    for row in rows:
        if row["run_dir"] is None:
            assert row["status"] == "lost-worker", row
            continue
        run_dir = Path(row["run_dir"])
        named.add(run_dir)
        assert run_dir.parent == (out / "runs").resolve() and run_dir.name.startswith(row["run_id"] + ".")
        if row["status"] != "done":
            assert run_dir.is_dir(), row
            continue
        assert json.loads((run_dir / "summary.json").read_text()) == json.loads(row["summary"]), row["run_id"]
        log = Path(row["log_path"])
        assert log.parent == run_dir, row["run_id"]
        assert hashlib.sha256(log.read_bytes()).hexdigest() == row["log_sha256"], row["run_id"]
    on_disk = set((out / "runs").resolve().iterdir()) if (out / "runs").exists() else set()
    assert on_disk == named, f"directories no row names: {sorted(map(str, on_disk - named))}"


class DaskCluster:
    """A cluster started the way a user starts one: `dask scheduler` and `dask worker --no-nanny` processes on
    localhost (stdout and stderr discarded), in `cwd`; a context manager that ends them all. Each is a
    `TiedProcess`: it dies with the test process too."""

    def __init__(self, cwd: Path, workers: int):
        import socket

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self.address, self.port, self.cwd, self.n = f"tcp://127.0.0.1:{port}", port, cwd, workers
        self.procs: list[subprocess.Popen] = []
        self.workers: list[subprocess.Popen] = []

    def _start(self, module: str, *args: str) -> subprocess.Popen:
        proc = TiedProcess("-m", module, *args, cwd=self.cwd, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).process
        self.procs.append(proc)
        return proc

    def start_worker(self) -> subprocess.Popen:
        return self._start("distributed.cli.dask_worker", self.address, "--nthreads", "1", "--no-nanny",
                           "--dashboard-address", ":0")

    def wait_for_workers(self, n: int, timeout_s: float = 120) -> None:
        """Until the scheduler has `n` workers (generous: a loaded machine starts a worker in seconds)."""
        from distributed import Client

        with Client(self.address, timeout=60) as client:
            client.wait_for_workers(n, timeout=timeout_s)

    def __enter__(self) -> DaskCluster:
        try:
            self._start("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(self.port),
                        "--dashboard-address", ":0")
            self.workers = [self.start_worker() for _ in range(self.n)]
            self.wait_for_workers(self.n)
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        for proc in reversed(self.procs):
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
