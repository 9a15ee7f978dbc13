"""A run request: every option of a bench run defined once (its name, type, default, help text and validation), and
`RunRequest`, the immutable description of one run built from them.

`RUN_OPTIONS` is the one table. From it come:
- the `bench run` and `bench host` argument parsers (`add_options`: each option where it applies, with the help
  text and default of that command), so the CLI reference page (sphinx-argparse) follows;
- the campaign spec's keys and their checks (`bench.campaign.spec.OPTIONS`);
- the pytest plugin's profile keys (`[run]`) and `thermal_bench.run(**options)`;
- `RunRequest.to_argv(command)` (the command line of a run) and `RunRequest.from_toml` / `from_mapping`, which
  round-trip with it.

An option a campaign or the plugin cannot set says why (`RunOption.placed`): its outputs (log, report, JUnit XML)
go into each run's own directory, the bus is chosen by the adapter (a campaign's runs each on a port of their own,
the plugin's from its --bench-* options). The bus options themselves are python-can's spelling
(`dbc.transport.add_bus_arguments`) and stay there, as do --json and --quiet (how a result is printed, not what
is run)."""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import UsageError
from bench.run import values
from bench.tomlspec import TableSpec
from dbc.contract import DEFAULT_REPLY_TIMEOUT_S
from host.session import DEFAULT_CONNECT_TIMEOUT_S

RUN, HOST = "run", "host"
BOTH = frozenset({RUN, HOST})
ONLY_RUN = frozenset({RUN})
ONLY_HOST = frozenset({HOST})

# why an adapter (a campaign, the pytest plugin) places an option itself rather than taking it from its user
OUTPUT = "an output: the adapter writes it into each run's own directory"
INTERACTIVE = "for a person at a terminal: an adapter's runs start at once"
FOLDED = "folded into `faults` (the adapter writes every fault there)"
HOST_ONLY = "`bench host` only: the adapter's attached target"


def _engines() -> tuple[str, ...]:
    from target_sim.engines import ENGINES

    return ENGINES


def _modes() -> tuple[str, ...]:
    from host.procedure import MODES

    return MODES


def _fault_kinds(command: str) -> str:
    from host.faults.spec import BUS_KINDS, KINDS

    return ", ".join(KINDS if command == RUN else BUS_KINDS)


@dataclass(frozen=True)
class RunOption:
    """One option of a run. `key` is its name in a campaign spec, a profile and `RunRequest`; `flag` its command
    line spelling. `parse` reads the command line's string (argparse type), `check` a TOML value (ValueError, one
    clause). `action`: 'store', 'store_true' (a flag) or 'append' (repeatable, a list). `commands`: where it
    applies (run, host); `per_command`: argparse keywords that differ in one command (its help, default, whether
    required). `placed`: why an adapter sets it itself (None: a campaign and the plugin take it from their user).
    `group`: the argparse group it is shown in (None: the command's own options)."""

    key: str
    flag: str
    help: str | Callable[[str], str]
    default: Any = None
    parse: Callable[[str], Any] | None = None
    check: Callable[[Any], Any] = values.path
    action: str = "store"
    choices: Callable[[], tuple[str, ...]] | None = None
    metavar: str | None = None
    commands: frozenset[str] = BOTH
    per_command: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    placed: str | None = None
    group: str | None = None
    argv_default: Any = None   # the value `to_argv` leaves out (default: `default`)

    @property
    def settable(self) -> bool:
        """A campaign spec and the plugin's profile take it from their user."""
        return self.placed is None

    def default_for(self, command: str = RUN) -> Any:
        return self.per_command.get(command, {}).get("default", self.default)

    def help_for(self, command: str, default: Any = None) -> str | None:
        """The help text in `command` (`{default}` in it: the default there, or `default` when given)."""
        text = self.per_command.get(command, {}).get("help", self.help)
        text = text(command) if callable(text) else text
        shown = self.default_for(command) if default is None else default
        return None if text is None else text.replace("{default}", str(shown))

    def argparse_kwargs(self, command: str) -> dict[str, Any]:
        kwargs: dict[str, Any] = {"help": self.help_for(command), "default": self.default_for(command)}
        if self.action == "store_true":
            kwargs.pop("default")
            kwargs["action"] = "store_true"
        elif self.action == "append":
            kwargs["action"] = "append"
            kwargs["default"] = []
        if self.parse is not None:
            kwargs["type"] = self.parse
        if self.choices is not None:
            kwargs["choices"] = self.choices()
        if self.metavar is not None:
            kwargs["metavar"] = self.metavar
        if self.per_command.get(command, {}).get("required"):
            kwargs["required"] = True
            kwargs.pop("default", None)
        if kwargs.get("help") is None:
            kwargs.pop("help")
        return kwargs


FAULT_GROUP = "fault injection (kill and freeze in lockstep only)"
ACCEPTANCE_GROUP = "acceptance (a CI's pass/fail rule, beside 'clean')"

RUN_OPTIONS: tuple[RunOption, ...] = (
    RunOption("data", "--data", "dataset CSV (default: the 40 °C validation run in out/data, generated if missing)",
              parse=Path, per_command={HOST: {"required": True,
                                              "help": "dataset CSV (bench.drive schema, or --mapping)"}}),
    RunOption("model", "--model", "model artifact (default: the packaged one)", parse=Path,
              per_command={HOST: {"help": "artifact the target must run (default: the packaged one)"}}),
    RunOption("mode", "--mode", "lockstep: each step waits for its reply (default); realtime: at the data rate x "
              "--speed", default="lockstep", choices=_modes, check=values.choice("lockstep", "realtime"),
              per_command={HOST: {"help": None}}),
    RunOption("speed", "--speed", "realtime speed factor (default 1)", default=1.0, parse=values.positive_float,
              check=values.number),
    RunOption("rows", "--rows", "replay only the first N data rows", parse=values.positive_int, check=values.rows,
              per_command={HOST: {"help": "replay only the first N rows"}}),
    RunOption("reply_timeout", "--reply-timeout", "seconds to wait for a step's reply before counting it missing "
              f"(default {DEFAULT_REPLY_TIMEOUT_S:g})", default=DEFAULT_REPLY_TIMEOUT_S,
              parse=values.positive_float, check=values.number,
              per_command={HOST: {"help": f"seconds per reply (default {DEFAULT_REPLY_TIMEOUT_S:g})"}}),
    RunOption("tolerate_gaps", "--tolerate-gaps", "exit 0 even with missing replies, sequence gaps or heartbeat loss "
              "(still reported); not for runs with injected faults (see --tolerate-faults)", default=False,
              action="store_true", check=values.flag,
              per_command={HOST: {"help": "exit 0 despite missing replies (still reported)"}}),
    RunOption("seed", "--seed", "seed of the generated default datasets", parse=int, check=values.whole,
              commands=ONLY_RUN),
    RunOption("mapping", "--mapping", "JSON or TOML mapping of your data files onto the bench's columns: names, "
              "units, derived columns (mean of several sensors), time column or none, separator and decimal mark",
              parse=Path, metavar="FILE"),
    RunOption("sample_period", "--sample-period", "the data's sample period in seconds, or 'auto': the mapping's, "
              "else inferred from the time column (a file without one needs it given) (default auto)",
              default="auto", parse=values.sample_period, check=values.period, metavar="S|auto",
              argv_default="auto"),
    RunOption("engine", "--engine", "what the target runs: the reference node in Python, or the node and model "
              "compiled for a Cortex-M4F in the emulated core, with measured cycles (the packaged artifacts ship "
              "their firmware; another artifact needs the compiler) (default {default})", default="python",
              choices=_engines, check=values.choice("python", "firmware"), commands=ONLY_RUN),
    RunOption("isr_rate", "--isr-rate", "with --engine firmware: a field-oriented current loop's interrupt "
              "(bench/firmware/foc_isr.c) preempts the node at this rate on the emulated core, and each model step's "
              "response time and the interrupt's CPU load go out in Timing5 into the summary and the report (the "
              "image is built with the compiler, once; default 0: no interrupt)", default=0,
              parse=values.non_negative_int, check=values.whole_at_least(0), metavar="HZ", commands=ONLY_RUN),
    RunOption("connect_timeout", "--connect-timeout", "seconds to wait for the target's heartbeat (default "
              f"{DEFAULT_CONNECT_TIMEOUT_S:g})", default=DEFAULT_CONNECT_TIMEOUT_S,
              parse=values.positive_float, check=values.number, commands=ONLY_HOST),
    RunOption("log", "--log", "bus log to write (default out/run/bench.blf)", default=Path("out/run/bench.blf"),
              parse=Path, placed=OUTPUT,
              per_command={HOST: {"default": Path("out/host/host.blf"), "help": "bus log, format by suffix .blf "
                                  ".asc .log .csv .mf4 (default out/host/host.blf)"}}),
    RunOption("report", "--report", "report directory (default out/run/report)", default=Path("out/run/report"),
              parse=Path, placed=OUTPUT, commands=ONLY_RUN),
    RunOption("no_report", "--no-report", "skip the report (metrics are still computed)", default=False,
              action="store_true", check=values.flag, placed=OUTPUT, commands=ONLY_RUN),
    RunOption("fault", "--fault", lambda command: "inject a fault kind: a probability per drive frame or row, or a "
              f"count for kill/freeze; repeatable. Kinds: {_fault_kinds(command)}", action="append",
              metavar="KIND=VALUE", placed=FOLDED, group=FAULT_GROUP),
    RunOption("faults", "--faults", lambda command: "several faults at once, e.g. drop=0.01,corrupt=0.001"
              + (",kill=1" if command == RUN else ""), default="", action="append", check=values.faults,
              metavar="K=V,K=V", group=FAULT_GROUP),
    RunOption("fault_seed", "--fault-seed", "seed of every fault choice (default 0: the same faults on every run)",
              default=0, parse=int, check=values.whole, metavar="N", group=FAULT_GROUP),
    RunOption("tolerate_faults", "--tolerate-faults", "exit 0 after injected faults if every one was detected and "
              "nothing else went wrong", default=False, action="store_true", check=values.flag, group=FAULT_GROUP),
    RunOption("target_events", "--target-events", "the target's detection journal (its --events file), to check "
              "that faults were detected", parse=Path, metavar="FILE", commands=ONLY_HOST, placed=HOST_ONLY),
    RunOption("criteria", "--criteria", "TOML file of named acceptance criteria ([criteria.NAME] tables: kind rmse, "
              "max_error, cycles, deadline_misses, missing_replies, heartbeat_losses, bus_load or regression, and a "
              "limit); each check's figure, limit and verdict go into the JSON and the report; exit status 1 when "
              "any fails, 2 for a bad file (before any work)", parse=Path, metavar="FILE", group=ACCEPTANCE_GROUP),
    RunOption("baseline", "--baseline", "a stored summary (the --json of bench run, host or analyze, or a report's "
              "metrics.json) for the regression criterion; without one in --criteria it adds \"no node's RMSE more "
              "than 5 %% worse\"", parse=Path, metavar="FILE", group=ACCEPTANCE_GROUP),
    RunOption("junit_xml", "--junit-xml", "write a JUnit XML report: one testcase for 'clean' and one per criterion, "
              "figure and limit in properties and the failure message, the log and report attached", parse=Path,
              metavar="FILE", placed=OUTPUT, group=ACCEPTANCE_GROUP),
    RunOption("wait_for_listener", "--wait-for-listener", "print the 'python -m can.logger ...' line first (with "
              "--quiet too), then wait SECONDS before anything is sent on the bus (a target is started, the host "
              "sends): the run's udp port exists only for this run, so a logger started from that line during the "
              "wait records all of it (or fix the bus beforehand: -c GROUP --bus-kwargs port=N)",
              parse=values.positive_float, check=values.number, metavar="SECONDS", placed=INTERACTIVE),
)

OPTION: dict[str, RunOption] = {o.key: o for o in RUN_OPTIONS}
SETTABLE: tuple[str, ...] = tuple(o.key for o in RUN_OPTIONS if o.settable)


def options_of(command: str) -> tuple[RunOption, ...]:
    return tuple(o for o in RUN_OPTIONS if command in o.commands)


def add_options(parser: argparse.ArgumentParser, command: str, keys: Iterable[str] | None = None) -> None:
    """The options of `command` (run or host) on `parser` (only `keys`, in their order, when given), each in its
    group, with that command's help text and default."""
    chosen = options_of(command) if keys is None else tuple(OPTION[k] for k in keys)
    groups: dict[str, Any] = {}
    for option in chosen:
        where = parser
        if option.group is not None:
            where = groups.get(option.group) or groups.setdefault(option.group, parser.add_argument_group(option.group))
        where.add_argument(option.flag, dest=option.key, **option.argparse_kwargs(command))


# ---------------------------------------------------------------- the request


def _request_fields() -> list[tuple[str, Any, Any]]:
    return [(o.key, Any, field(default=o.default)) for o in RUN_OPTIONS if o.key != "fault"]


class _RequestMethods:
    """What every RunRequest does (the dataclass's fields come from RUN_OPTIONS)."""

    def options(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def to_argv(self, command: str = RUN) -> list[str]:
        """The command line (after `bench run` or `bench host`) of this request: every option that applies to
        `command` and differs from its default there."""
        argv: list[str] = []
        for option in options_of(command):
            if option.key == "fault":
                continue
            value = getattr(self, option.key)
            # a value at the option's default (the request's, or this command's own) goes without saying
            unset = (option.default, option.default_for(command), option.argv_default)
            if value is None or value in unset or (option.action == "store_true" and not value):
                continue
            if option.action == "store_true":
                argv.append(option.flag)
            else:
                argv += [option.flag, repr(value) if isinstance(value, float) else str(value)]
        return argv

    def with_options(self, **changes: Any) -> RunRequest:
        return type(self).from_mapping({**self.options(), **changes}, "the request")


RunRequest = dataclasses.make_dataclass("RunRequest", _request_fields(), bases=(_RequestMethods,), frozen=True)
RunRequest.__module__ = __name__
RunRequest.__doc__ = ("One run, immutable: a field per option of RUN_OPTIONS (but `fault`, folded into `faults`), "
                      "each at its default unless given.")


def check_value(key: str, value: Any) -> Any:
    """A TOML value of option `key`, checked and normalized (ValueError, one clause)."""
    return OPTION[key].check(value)


def _from_mapping(cls, options: Mapping[str, Any], where: str) -> RunRequest:
    """The request of `options` (keys with `-` or `_`), each checked by its option's own check (the TOML files'
    mechanism, `bench.tomlspec.TableSpec`): UsageError naming `where` and the key for an unknown key or a bad
    value. None and a Path stand as given (a request made in code)."""
    given = {key.strip().replace("-", "_"): value for key, value in options.items()}
    table = TableSpec("", {key: option.check for key, option in OPTION.items() if key != "fault"},
                      advice=f"it names no run option; use {', '.join(SETTABLE)}")
    as_given = {key: value for key, value in given.items() if key in table.keys and (
        value is None or (OPTION[key].parse is Path and isinstance(value, Path)))}
    checked = table.read({k: v for k, v in given.items() if k not in as_given}, where, UsageError)
    return cls(**as_given, **checked)


def _from_toml(cls, text: str, where: str = "the run request") -> RunRequest:
    """The request of a TOML text of `key = value` lines (as a campaign's [fixed] or a profile's [run])."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{where} is not TOML ({exc})") from None
    return cls.from_mapping(doc, where)


def _to_toml(self) -> str:
    """The options that differ from their defaults as TOML lines (`from_toml` reads them back)."""
    lines = []
    for key, value in self.options().items():
        if value is None or value == OPTION[key].default:
            continue
        value = str(value) if isinstance(value, Path) else value
        text = ("true" if value else "false") if isinstance(value, bool) else (
            f'"{value}"' if isinstance(value, str) else repr(value))
        lines.append(f"{key} = {text}")
    return "\n".join(lines) + ("\n" if lines else "")


def _from_args(cls, args: argparse.Namespace) -> RunRequest:
    """The request of a parsed `bench run` / `bench host` command line (the options its parser has)."""
    known = {k: getattr(args, k) for k in cls.__dataclass_fields__ if hasattr(args, k)}
    listed = [*(getattr(args, "fault", None) or []), *(getattr(args, "faults", None) or [])]
    known["faults"] = ",".join(listed)
    return cls(**known)


RunRequest.from_mapping = classmethod(_from_mapping)
RunRequest.from_toml = classmethod(_from_toml)
RunRequest.from_args = classmethod(_from_args)
RunRequest.to_toml = _to_toml
