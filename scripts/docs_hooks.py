"""MkDocs hooks: the reference pages and the evaluation reports, generated at build time.

``mkdocs build`` (``mkdocs.yml``: ``hooks``) calls these; nothing here runs
in the package. Every generated page comes from the code or from data, so
that no page can drift from what it describes:

* ``reference/cli.md``: every command and option of the ``chaintwin`` command
  line, read from the Typer application's click commands;
* ``reference/http.md``: every operation of the HTTP API, its parameters,
  request fields and responses, read from the web application's OpenAPI
  document (``app.openapi()`` on an empty throwaway store);
* ``evaluation/<name>.md``: a page per ``docs/evaluation/<name>.json`` the
  evaluation scripts write, its numbers as tables; a hand-written page of
  the same name (what is judged and how to run it) gets the tables where it
  says ``<!-- evaluation-tables -->``.

Nav entries whose page is missing (pages another branch adds) are left out
with a note instead of failing the strict build.
"""

from __future__ import annotations

import json
import logging
import tempfile
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files
from mkdocs.structure.pages import Page

log = logging.getLogger("mkdocs.hooks.chaintwin")

EVALUATION = "evaluation"
MARKER = "<!-- evaluation-tables -->"


# ----------------------------------------------------------------------- helpers
def _cell(value: Any) -> str:
    """A value as one Markdown table cell (pipes and angle brackets escaped)."""
    if value is None:
        text = "null"
    elif isinstance(value, float):
        text = f"{value:.4g}"
    elif isinstance(value, bool):
        text = "yes" if value else "no"
    elif isinstance(value, dict | list):
        text = json.dumps(value, ensure_ascii=False)
    else:
        text = str(value)
    text = " ".join(text.split())
    if not (len(text) > 1 and text.startswith("`") and text.endswith("`")):
        # a code span shows < and & as they are; elsewhere they are HTML
        text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return text.replace("|", "\\|")


def _table(header: list[str], rows: list[list[Any]]) -> list[str]:
    out = ["| " + " | ".join(_cell(h) for h in header) + " |"]
    out.append("|" + "---|" * len(header))
    out += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return [*out, ""]


# ------------------------------------------------------------------ command line
# Typer builds click-style commands (its own copy of click): read them by their
# click interface (list_commands, get_help_record, collect_usage_pieces).
def _command_page(command: Any, path: list[str], parent: Any) -> list[str]:
    ctx = command.context_class(command, info_name=path[-1], parent=parent)
    out = [f"{'#' * min(len(path) + 1, 4)} `{' '.join(path)}`", ""]
    if command.help:
        out += [command.help.replace("\b\n", "").strip(), ""]
    pieces = " ".join(command.collect_usage_pieces(ctx))
    out += ["```text", f"{' '.join(path)} {pieces}".rstrip(), "```", ""]
    rows = []
    for param in command.params:
        if getattr(param, "hidden", False):
            continue
        record = param.get_help_record(ctx)
        if record is None:
            continue
        names, text = record
        rows.append([f"`{names}`", text])
    if rows:
        out += _table(["argument or option", "what"], rows)
    if hasattr(command, "list_commands"):
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            if sub is not None and not getattr(sub, "hidden", False):
                out += _command_page(sub, [*path, name], ctx)
    return out


def cli_reference() -> str:
    """The command-line reference: every command and option, from the Typer app."""
    import typer

    from chaintwin.cli.app import app

    root = typer.main.get_command(app)
    out = [
        "# Command line",
        "",
        "Generated from the command line's own definitions when the site is built;",
        "`chaintwin COMMAND --help` prints the same. The options before the command",
        "(`chaintwin --max-file-mb 200 inspect ...`) apply to every command.",
        "",
    ]
    out += _command_page(root, ["chaintwin"], None)[2:]
    return "\n".join(out) + "\n"


# -------------------------------------------------------------------- HTTP API
def _schema(doc: dict[str, Any], schema: dict[str, Any]) -> dict[str, Any]:
    ref = schema.get("$ref")
    if isinstance(ref, str):
        resolved: dict[str, Any] = doc
        for part in ref.removeprefix("#/").split("/"):
            resolved = resolved[part]
        return resolved
    return schema


def _type(doc: dict[str, Any], schema: dict[str, Any]) -> str:
    schema = _schema(doc, schema)
    if "anyOf" in schema:
        return " or ".join(_type(doc, s) for s in schema["anyOf"])
    if schema.get("type") == "array":
        return f"array of {_type(doc, schema.get('items', {}))}"
    if "enum" in schema:
        return " \\| ".join(f"`{v}`" for v in schema["enum"])
    return str(schema.get("type") or schema.get("title") or "object")


def _fields(doc: dict[str, Any], schema: dict[str, Any]) -> list[list[Any]]:
    schema = _schema(doc, schema)
    required = set(schema.get("required", []))
    rows = []
    for name, prop in schema.get("properties", {}).items():
        rows.append(
            [
                f"`{name}`",
                _type(doc, prop),
                "yes" if name in required else "",
                _schema(doc, prop).get("description", prop.get("description", "")),
            ]
        )
    return rows


def http_reference(doc: dict[str, Any]) -> str:
    """The HTTP reference: every operation of an OpenAPI document."""
    info = doc.get("info", {})
    out = [
        "# HTTP API",
        "",
        f"{info.get('title', 'chaintwin')} {info.get('version', '')}: generated from the",
        "service's OpenAPI document when the site is built. A running `chaintwin serve`",
        "serves the same document at `/openapi.json`, with `/docs` and `/redoc` to try it.",
        "",
    ]
    for path, methods in doc.get("paths", {}).items():
        for method, op in methods.items():
            if method not in {"get", "post", "put", "patch", "delete"}:
                continue
            out += [f"## `{method.upper()} {path}`", ""]
            if op.get("summary"):
                out += [op["summary"], ""]
            if op.get("description"):
                out += [op["description"].strip(), ""]
            params = [
                [
                    f"`{p['name']}`",
                    p.get("in", ""),
                    _type(doc, p.get("schema", {})),
                    "yes" if p.get("required") else "",
                    p.get("description", ""),
                ]
                for p in op.get("parameters", [])
            ]
            if params:
                out += ["Parameters:", ""]
                out += _table(["name", "in", "type", "required", "what"], params)
            body = op.get("requestBody", {}).get("content", {})
            for media, content in body.items():
                fields = _fields(doc, content.get("schema", {}))
                out += [f"Request body (`{media}`):", ""]
                if fields:
                    out += _table(["field", "type", "required", "what"], fields)
            responses = [
                [code, r.get("description", "")] for code, r in op.get("responses", {}).items()
            ]
            if responses:
                out += _table(["status", "meaning"], responses)
    return "\n".join(out) + "\n"


def openapi_document() -> dict[str, Any]:
    """The web application's OpenAPI document, built over an empty throwaway store."""
    from chaintwin.store.store import Store
    from chaintwin.web.app import create_app

    with tempfile.TemporaryDirectory() as tmp:
        store = Store(f"sqlite:///{Path(tmp) / 'reference.db'}")
        try:
            document: dict[str, Any] = create_app(store, {}).openapi()
        finally:
            store.close()
    return document


# ------------------------------------------------------------------ evaluation
def _render_value(name: str, value: Any, level: int) -> list[str]:
    heading = "#" * min(level, 6)
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        columns: list[str] = []
        for row in value:
            columns += [k for k in row if k not in columns]
        return [
            f"{heading} {name}",
            "",
            *_table(columns, [[row.get(c) for c in columns] for row in value]),
        ]
    if isinstance(value, dict):
        flat = {k: v for k, v in value.items() if not isinstance(v, dict | list) or not v}
        nested = {k: v for k, v in value.items() if k not in flat}
        out = [f"{heading} {name}", ""]
        if flat:
            out += _table(["quantity", "value"], [[k, v] for k, v in flat.items()])
        for key, sub in nested.items():
            out += _render_value(key, sub, level + 1)
        return out
    return [f"{heading} {name}", "", *_table(["value"], [[value]])]


def evaluation_tables(data: Any) -> str:
    """The tables of one evaluation's JSON: scalars first, then each table or group."""
    if not isinstance(data, dict):
        return "\n".join(_render_value("Results", data, 2)) + "\n"
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict | list)}
    out: list[str] = []
    if scalars:
        out += [
            "## Summary",
            "",
            *_table(["quantity", "value"], [[k, v] for k, v in scalars.items()]),
        ]
    for key, value in data.items():
        if key not in scalars:
            out += _render_value(key, value, 2)
    return "\n".join(out) + "\n"


def _evaluation_files(docs_dir: Path) -> list[Path]:
    return sorted((docs_dir / EVALUATION).glob("*.json"))


def _evaluation_index(names: list[str], hand_written: set[str]) -> str:
    out = [
        "# Evaluation reports",
        "",
        "How well the twin does, judged on the virtual conveyor against the truth it",
        "was given. Each report is generated when the site is built from the JSON its",
        "script writes under `docs/evaluation/`; run the script again to bring it up",
        "to date (the page of each report says which).",
        "",
    ]
    pages = sorted(set(names) | hand_written)
    out += [f"* [{name}]({name}.md)" for name in pages] if pages else ["No report yet."]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------ nav pruning
def _prune(nav: Any, present: set[str]) -> Any:
    """``nav`` without the entries whose page is not among ``present``."""
    if isinstance(nav, list):
        kept = [_prune(item, present) for item in nav]
        return [item for item in kept if item is not None]
    if isinstance(nav, dict):
        ((title, target),) = nav.items()
        pruned = _prune(target, present)
        return None if pruned is None or pruned == [] else {title: pruned}
    if isinstance(nav, str) and nav.endswith(".md") and "://" not in nav and nav not in present:
        log.info("nav: %s is not in this tree yet; left out", nav)
        return None
    return nav


# ------------------------------------------------------------------------ hooks
def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Add the generated pages, and drop nav entries whose page does not exist."""
    docs_dir = Path(config["docs_dir"])
    generated = {
        "reference/cli.md": cli_reference(),
        "reference/http.md": http_reference(openapi_document()),
    }
    json_files = _evaluation_files(docs_dir)
    names = [p.stem for p in json_files]
    hand_written = {
        Path(f.src_uri).stem
        for f in files.documentation_pages()
        if f.src_uri.startswith(f"{EVALUATION}/") and f.src_uri != f"{EVALUATION}/index.md"
    }
    for path in json_files:
        if path.stem not in hand_written:
            title = path.stem.replace("-", " ").capitalize()
            generated[f"{EVALUATION}/{path.stem}.md"] = (
                f"# {title}\n\nGenerated from `docs/{EVALUATION}/{path.name}`.\n\n"
                + evaluation_tables(json.loads(path.read_text(encoding="utf-8")))
            )
    if files.get_file_from_path(f"{EVALUATION}/index.md") is None:
        generated[f"{EVALUATION}/index.md"] = _evaluation_index(names, hand_written)
    for uri, content in generated.items():
        files.append(File.generated(config, uri, content=content))
    present = {f.src_uri for f in files.documentation_pages()}
    if config["nav"] is not None:
        reports = sorted(u for u in present if u.startswith(f"{EVALUATION}/"))
        _add_reports(config["nav"], [u for u in reports if u != f"{EVALUATION}/index.md"])
        config["nav"] = _prune(config["nav"], present)
    return files


def _add_reports(nav: Any, reports: list[str]) -> bool:
    """Append the evaluation reports to the nav section that holds the evaluation index."""
    if isinstance(nav, list):
        if f"{EVALUATION}/index.md" in nav:
            nav += [r for r in reports if r not in nav]
            return True
        return any(_add_reports(item, reports) for item in nav)
    if isinstance(nav, dict):
        return any(_add_reports(v, reports) for v in nav.values())
    return False


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    """A hand-written evaluation page: its JSON's tables where it asks for them."""
    uri = page.file.src_uri
    if not uri.startswith(f"{EVALUATION}/") or MARKER not in markdown:
        return markdown
    path = Path(config["docs_dir"]) / EVALUATION / f"{Path(uri).stem}.json"
    if not path.is_file():
        tables = (
            f"*No results yet: `docs/{EVALUATION}/{path.name}` is written by the script above.*\n"
        )
    else:
        tables = evaluation_tables(json.loads(path.read_text(encoding="utf-8")))
    return markdown.replace(MARKER, tables)
