"""The API's paths as the pages spell them: only frontend/js/api.js (`paths`, one named function per path) writes
"/api/...", and every path there is one the API serves (a renamed route fails here, not in a browser test)."""

from __future__ import annotations

import re
from pathlib import Path

JS = Path(__file__).resolve().parents[3] / "frontend" / "js"
API_JS = JS / "api.js"
LITERAL = re.compile(r"""["'`]/api/""")
COMMENT = re.compile(r"(^|\s)//.*$")
# `name: (...) => "/api/..."` or a template literal; its ${...} parts are parameters (a query string: left out).
ENTRY = re.compile(r"""^\s*(\w+): \(.*?\)\s*=>\s*(?:\n\s*)?([`"])(/api/[^`"]*)\2""", re.M | re.S)


def _paths() -> dict[str, str]:
    text = API_JS.read_text()
    block = text[text.index("export const paths"):]
    block = block[:block.index("});")]
    found = {}
    for name, _quote, path in ENTRY.findall(block):
        path = re.sub(r"\$\{query\([^}]*\}\)\}$", "", path)  # the query string, if any
        found[name] = re.sub(r"\$\{[^}]+\}", "{x}", path)
    return found


def test_only_api_js_spells_api_paths():
    offenders = []
    for path in sorted(JS.glob("*.js")):
        if path == API_JS:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if LITERAL.search(COMMENT.sub("", line)):
                offenders.append(f"{path.name}:{number}: {line.strip()}")
    assert not offenders, "call the named path in api.js (`paths`) instead:\n" + "\n".join(offenders)


def test_every_named_path_is_served(sqlite_env):
    served = [re.compile("^" + re.sub(r"\{[^}]+\}", "[^/]+", p) + "$")
              for p in sqlite_env.client.get("/openapi.json").json()["paths"]]
    named = _paths()
    assert len(named) >= 40, named  # the parser found them (a format change must not make this pass vacuously)
    for queue in ("annotate", "review"):
        missing = [f"{name}: {path}" for name, path in named.items()
                   if not any(s.match(path.replace("/api/{x}/", f"/api/{queue}/", 1)) for s in served)]
        assert not missing, f"frontend/js/api.js names paths the API does not serve ({queue}):\n" + "\n".join(missing)
