"""Sphinx extension: the pages generated from the project's own definitions at build time.

* `_generated/protocol.md` from `dbc/thermal_bench.dbc` (through `dbc.database.contract()`, i.e. cantools): the
  contract's version and general comment (the E2E scheme), its nodes, and per message the id, sender, cycle time,
  E2E data id, comment and every signal (start bit, length, signedness, scale/offset, unit, range, value table,
  comment).
* `_generated/artifact-schema.md` from `target_sim.artifact` (SCHEMA, SCHEMA_VERSION, READABLE_VERSIONS, the common
  fields) and the registries `target_sim.losses.LOSS_KINDS`, `target_sim.modelkinds.MODEL_KINDS` and
  `target_sim.kinds.REALIZATIONS` (each kind's own fields and shapes, as the loader asks them).
* `_generated/results.md`, `table5.md`, `ipm-accuracy.md` and the observer's `observer.md`, `observer-ipm.md` and
  `observer-forms.md` from the benchmark records in `docs/results/` (`results_page`).

The pages are written only when their text changes, so an unchanged contract does not rebuild them. `render_*` are
plain functions, so a check (`docs/check_generated.py`) can call them without Sphinx.
"""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1]
GENERATED = DOCS / "_generated"


def _text(text: object) -> str:
    """Text of the DBC as one line of Markdown: angle brackets and asterisks are not markup."""
    return re.sub(r"([<>*_|])", r"\\\1", " ".join(str(text).split()))


def _cell(text: object) -> str:
    """A value as one Markdown table cell."""
    return _text(text) if text not in (None, "") else "–"


def _num(value: float) -> str:
    return f"{value:g}"


def _dbc_general_comment(path: Path) -> str:
    """The DBC's general comment (`CM_ "...";`), which cantools does not keep."""
    match = re.search(r'^CM_ "((?:[^"\\]|\\.)*)";', path.read_text(encoding="utf-8"), re.MULTILINE)
    return match.group(1) if match else ""


def render_protocol() -> str:
    from dbc.contract import DBC_PATH
    from dbc.database import contract

    c = contract()
    database = c.database
    lines = [
        "<!-- generated from dbc/thermal_bench.dbc by docs/_ext/bench_docs.py; do not edit -->",
        "",
        "(protocol-contract)=",
        "## The contract",
        "",
        f"`{DBC_PATH.name}` version {c.version}, {len(c.by_name)} messages, generated from the file when these pages "
        "were built. The DBC's own description, the E2E scheme included:",
        "",
        f"> {_text(_dbc_general_comment(DBC_PATH))}",
        "",
        "### Nodes",
        "",
        "| node | sends | description |",
        "|---|---|---|",
    ]
    for node in database.nodes:
        sent = ", ".join(m.name for m in c.by_name.values() if m.sender == node.name)
        lines.append(f"| `{node.name}` | {_cell(sent)} | {_cell(node.comment)} |")
    lines += ["", "### Messages", "",
              "| message | id | sender | cycle time | E2E data id | application signals |",
              "|---|---|---|---|---|---|"]
    for m in sorted(c.by_name.values(), key=lambda m: m.frame_id):
        cycle = f"{m.cycle_time_ms} ms" if m.cycle_time_ms else "on event"
        signals = ", ".join(s.dbc_name for s in m.signals)
        lines.append(f"| [{m.name}](#msg-{m.name.lower()}) | `0x{m.frame_id:03X}` | {m.sender} | {cycle} "
                     f"| `0x{m.data_id:02X}` | {_cell(signals)} |")
    for m in sorted(c.by_name.values(), key=lambda m: m.frame_id):
        message = m.message
        cycle = f"{m.cycle_time_ms} ms" if m.cycle_time_ms else "on event"
        lines += ["", f"(msg-{m.name.lower()})=", f"### {m.name}", "",
                  f"Id `0x{m.frame_id:03X}` ({m.frame_id}), DLC {message.length}, sent by `{m.sender}`, "
                  f"cycle time {cycle}, E2E data id `0x{m.data_id:02X}`.", "",
                  _cell(message.comment), "",
                  "| signal | start bit | length | signed | scale | offset | unit | range | comment |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for s in message.signals:
            if s.is_float:
                kind = "IEEE float"
            else:
                kind = "yes" if s.is_signed else "no"
            low = _num(s.minimum) if s.minimum is not None else "–"
            high = _num(s.maximum) if s.maximum is not None else "–"
            comment = s.comment or ""
            if s.choices:
                values = "; ".join(f"{int(k)} = {v}" for k, v in sorted(s.choices.items()))
                comment = f"{comment} Values: {values}."
            lines.append(f"| `{s.name}` | {s.start} | {s.length} | {kind} | {_num(s.scale)} | {_num(s.offset)} "
                         f"| {_cell(s.unit)} | {low} … {high} | {_cell(comment)} |")
    return "\n".join(lines) + "\n"


def _keys(keys: tuple[str, ...]) -> str:
    return "`" + ".".join(keys) + "`"


def render_artifact_schema() -> str:
    from target_sim import artifact
    from target_sim.kinds import REALIZATIONS
    from target_sim.losses import LOSS_KINDS, LOSS_OUTPUTS
    from target_sim.modelkinds import MODEL_KINDS

    lines = [
        "<!-- generated from target_sim/artifact.py and the kind registries by docs/_ext/bench_docs.py; "
        "do not edit -->",
        "",
        "## The schema as the loader checks it",
        "",
        f"* `schema`: `{artifact.SCHEMA}`",
        f"* `schema_version`: {artifact.SCHEMA_VERSION} (versions this target reads: "
        f"{', '.join(str(v) for v in artifact.READABLE_VERSIONS)})",
        f"* `model_kind`: one of {', '.join(f'`{k}`' for k in MODEL_KINDS.names())} (below)",
        f"* `realization`: one of {', '.join(f'`{k}`' for k in REALIZATIONS.names())} (below)",
        f"* `losses.model`: one of {', '.join(f'`{k}`' for k in LOSS_KINDS.names())} (below; absent in version 1: "
        f"`{artifact.loss_model_of({})}`)",
        f"* `timing.dt_s`, `timing.data_sample_period_s`: seconds, {_num(artifact.TIMING_RANGE_S[0])} to "
        f"{_num(artifact.TIMING_RANGE_S[1])}",
        f"* `outputs`: the temperature nodes in order, {', '.join(f'`{o}`' for o in artifact.OUTPUTS)}",
        "* `sha256`: over the canonical JSON of everything else (`target_sim.artifact.canonical_bytes`)",
        "",
        "Every array field is an object `{\"shape\", \"f64\", \"f32_hex\"}` (`target_sim.artifact.encode_array`): the "
        "float64 values and the exact float32 each becomes, as `float.hex()`; a scalar has shape `[]`. The loader "
        "checks the shape, that each float32 is the rounding of its float64 twin and that it is finite.",
        "",
        "### Fields of every artifact",
        "",
        "| field | shape |",
        "|---|---|",
    ]
    for name in artifact.LPTN_PARAMETERS:
        lines.append(f"| {_keys(('lptn', 'parameters', name))} | scalar |")
    lines.append(f"| {_keys(('lptn', 'speed_max_rpm'))} | scalar |")
    for name in ("current_max_A", "alpha_cu_per_K", "copper_reference_C"):
        lines.append(f"| {_keys(('losses', name))} | scalar |")
    lines += ["", "### Loss models (`losses.model`, `target_sim.losses.LOSS_KINDS`)", "",
              f"Each computes the five loss inputs {', '.join(f'`{o}`' for o in LOSS_OUTPUTS)} and owns these "
              "fields under `losses` (the sizes of a table or axis come from the artifact's own axes).", ""]
    for name, kind in LOSS_KINDS.items():
        fields = kind.fields({})
        shapes = kind.shapes({})
        lines += [f"#### `{name}`", "", f"{kind.summary}. Reads from a data row: "
                  f"{', '.join(f'`{i}`' for i in kind.inputs)}.", "", "| field | shape |", "|---|---|"]
        for keys in fields:
            shape = shapes.get(keys)
            shown = "scalar" if shape is None else f"{len(shape)}-D"
            lines.append(f"| {_keys(('losses', *keys))} | {shown} |")
        lines.append("")
    lines += ["### Model kinds (`model_kind`, `target_sim.modelkinds.MODEL_KINDS`)", "",
              "| kind | summary | linear block | input nonlinearity | any realization |", "|---|---|---|---|---|"]
    for name, kind in MODEL_KINDS.items():
        lines.append(f"| `{name}` | {_cell(kind.summary)} | {'yes' if kind.linear_block else 'no'} "
                     f"| {'yes' if kind.input_nonlinearity else 'no'} | {'yes' if kind.realizations else 'no'} |")
    for name, kind in MODEL_KINDS.items():
        lines += ["", f"#### `{name}`", ""]
        realizations = REALIZATIONS.names() if kind.realizations else ("physical",)
        by_fields: dict[tuple, list[str]] = {}
        for realization in realizations:
            content = {"model_kind": name, "realization": realization}
            fields = tuple(kind.fields(content))
            by_fields.setdefault(fields, []).append(realization)
        if not any(by_fields):
            lines.append("No fields of its own: the step is rebuilt from `lptn` every step.")
            continue
        for fields, names in by_fields.items():
            content = {"model_kind": name, "realization": names[0]}
            shapes = kind.shapes(content)
            lines += [f"Realizations {', '.join(f'`{r}`' for r in names)}:", "", "| field | shape |", "|---|---|"]
            for keys in fields:
                shape = shapes.get(keys)
                lines.append(f"| {_keys(keys)} | {'scalar' if not shape else list(shape)} |")
            lines.append("")
    from target_sim.observer import OBSERVER_FORMS

    lines += ["", f"### Observer (optional; `observer`, version {artifact.OBSERVER_VERSION})", "",
              f"An artifact of a kind with a linear block may carry a Kalman observer (`target_sim.observer`); it is "
              f"then written as version {artifact.OBSERVER_VERSION}, and one without an observer as version 2. "
              f"`observer.node` names the measured output ({', '.join(f'`{o}`' for o in artifact.OUTPUTS)}), "
              "`observer.column` the dataset column of the sensor, `observer.lag_s` its time constant (recorded), "
              "`observer.form` the covariance form the target deploys. The loader checks R > 0, Q symmetric positive "
              "semidefinite, P0 and P_ss symmetric positive definite and the per-node process noise non-negative.",
              "", "| field | shape |", "|---|---|"]
    for key, shape in artifact.OBSERVER_ARRAYS.items():
        lines.append(f"| {_keys(('observer', key))} | {'scalar' if not shape else list(shape)} |")
    lines += ["", "| form | summary |", "|---|---|"]
    for name, form in OBSERVER_FORMS.items():
        lines.append(f"| `{name}` | {_cell(form.summary)} |")
    from target_sim.observer.measurements import MEASUREMENT_KINDS

    lines += ["", "Observer section version 2 (`observer.version`: 2; without it, version 1 above: one unlagged "
              "sensor) "
              "lists its measurements in order in `observer.measurements` (each `kind`, `columns`, `node` and its "
              "encoded `arrays`), names the filter's states in `observer.states` (the 4 model states, one lag state "
              "per lagged measurement, then the bias) and sets `observer.bias`: null (no bias state) or a heat bias, W "
              "into one node the loss model misses, a random walk heating through that node's loss column of B: "
              + ", ".join(f"`{kind}` (the {artifact.OUTPUTS[index]}: column {index}, P_{artifact.OUTPUTS[index][0]})"
                          for kind, index in artifact.BIAS_KINDS.items())
              + "; `observer.consider` (absent or null: none) names consider states, which a measurement that "
              "does not read them never updates (the gain's rows zero, the covariance that of that gain): "
              + ", ".join(f"`{kind}` (the {', '.join(nodes)} node{'s' * (len(nodes) > 1)} a measurement does not "
                          "read, and a bias heating one of them)"
                          for kind, nodes in artifact.CONSIDER_KINDS.items())
              + "; `observer.consider_release_C2` (an encoded variance, °C²; absent or null: held always) is the "
              "key-on release: while the magnet's variance before an update exceeds it, no measurement holds the "
              "magnet (nor a magnet bias)"
              + "; Q, P0 and "
              "P_ss are then n × n with n = len(states), `q_nodes_C2` has n entries and K_ss one row per "
              "measurement. `node`, `column`, `offset_C`, `R` and `lag_s` describe the first measurement.", "",
              "| measurement kind | summary |", "|---|---|"]
    for name, kind in MEASUREMENT_KINDS.items():
        lines.append(f"| `{name}` | {_cell(kind.summary)} |")
    lines += ["", "### Realizations (`realization`, `target_sim.kinds.REALIZATIONS`)", "",
              "| realization | form | summary |", "|---|---|---|"]
    for name, realization in REALIZATIONS.items():
        form = "delta: x ← x + Δ·(A x + B ũ), y = C x + r" if realization.delta else "shift: x ← A x + B u, y = C x"
        lines.append(f"| `{name}` | {form} | {_cell(realization.summary)} |")
    return "\n".join(lines) + "\n"


def _results_pages() -> dict:
    """The measured pages (`results_page`, from the benchmark records in `docs/results/`)."""
    import results_page

    return {"results.md": results_page.render_results, "table5.md": results_page.render_table5,
            "ipm-accuracy.md": results_page.render_ipm, "observer.md": results_page.render_observer,
            "observer-ipm.md": results_page.render_observer_ipm,
            "observer-forms.md": results_page.render_observer_forms}


PAGES = {"protocol.md": render_protocol, "artifact-schema.md": render_artifact_schema, **_results_pages()}


def write_pages(directory: Path = GENERATED) -> list[Path]:
    directory.mkdir(exist_ok=True)
    written = []
    for name, render in PAGES.items():
        path = directory / name
        text = render()
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


def _builder_inited(app) -> None:
    write_pages()


# Links of the Markdown files at the top of the repository, as they read on its front page, and the page each
# becomes when the docs include the file.
_INCLUDED_LINKS = {"CONTRIBUTING.md": "development.md", "CHANGELOG.md": "changelog.md"}


def _include_read(app, relative_path, parent_docname, content) -> None:
    """Links between the repository's own Markdown files point at the pages that include them."""
    if Path(relative_path).parent != Path(".."):
        return
    text = content[0]
    for source, page in _INCLUDED_LINKS.items():
        text = text.replace(f"]({source})", f"]({page})")
    content[0] = text


_CODE = re.compile(r"(``?[^`]*``?)")


def _plain(text: str) -> str:
    """Outside code spans: the characters reStructuredText reads as markup the docstrings do not mean."""
    parts = _CODE.split(text)
    for i in range(0, len(parts), 2):
        part = parts[i].replace("\\", "\\\\")
        part = re.sub(r"([|*])", r"\\\1", part)
        part = re.sub(r"(\w)_(?=\W|$)", r"\1\\_", part)
        parts[i] = part
    return "".join(parts)


_BULLET = re.compile(r"^(\s*)([-*+]|\d+\.|\(\w\))\s+")


def _docstring_as_text(lines: list[str]) -> list[str]:
    """A docstring written as plain prose with `code` spans, made safe for reStructuredText.

    The project's docstrings are prose, not reST: a `|` or `*` is a character, an indented continuation line is
    not a block quote, and a table of dashes is not a substitution. So, outside code spans, markup characters are
    escaped (list bullets kept), and a line indented deeper than the line before it, where that line does not open a
    list item, is set off by blank lines (a quoted block rather than a broken definition list). Doctest and
    literal blocks (`::`) are left as they are.
    """
    out: list[str] = []
    previous_indent = None
    in_literal = False
    literal_indent = 0
    bullet_body: int | None = None
    for line in lines:
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if not stripped:
            out.append(line)
            continue
        if in_literal:
            if indent > literal_indent:
                out.append(line)
                continue
            in_literal = False
        bullet = _BULLET.match(line)
        if bullet and bullet_body is None and out and out[-1].strip():
            out.append("")          # a list that starts right under a sentence
        if bullet:
            text = line[bullet.end():]
            line = line[:bullet.end()] + _plain(text)
        else:
            line = " " * indent + _plain(stripped)
        if previous_indent is not None and out and out[-1].strip():
            continuation = bullet_body is not None and indent == bullet_body
            if indent != previous_indent and not continuation and not bullet:
                out.append("")
            elif bullet and indent != previous_indent and bullet_body is None:
                out.append("")
        if bullet:
            bullet_body = len(bullet.group(0))
        elif bullet_body is not None and indent < bullet_body:
            bullet_body = None
            if out and out[-1].strip():
                out.append("")
        out.append(line)
        previous_indent = indent if not bullet else bullet_body
        if stripped.endswith("::"):
            in_literal = True
            literal_indent = indent
            out.append("")
    return out


def _process_docstring(app, what, name, obj, options, lines) -> None:
    lines[:] = _docstring_as_text(lines)


_TEXT_KEYS = ("help", "description", "epilog")


def _safe_parser_texts(data):
    """sphinx-argparse's description of a parser with every help text made safe as `_docstring_as_text` does."""
    if isinstance(data, dict):
        for key, value in data.items():
            if key in _TEXT_KEYS and isinstance(value, str):
                data[key] = "\n".join(_docstring_as_text(value.split("\n")))
            else:
                _safe_parser_texts(value)
    elif isinstance(data, list):
        for item in data:
            _safe_parser_texts(item)
    return data


def _wrap_sphinx_argparse() -> None:
    """The command reference renders the CLI's own help texts, which are prose, not reST (see
    `_docstring_as_text`): sphinx-argparse's reading of the parser is wrapped to make them safe."""
    import sphinxarg.ext

    original = sphinxarg.ext.parse_parser
    if getattr(original, "_bench_docs", False):
        return

    def parse_parser(*args, **kwargs):
        return _safe_parser_texts(original(*args, **kwargs))

    parse_parser._bench_docs = True
    sphinxarg.ext.parse_parser = parse_parser


def setup(app):
    _wrap_sphinx_argparse()
    app.connect("builder-inited", _builder_inited)
    app.connect("include-read", _include_read)
    app.connect("autodoc-process-docstring", _process_docstring)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
