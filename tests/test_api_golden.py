"""Every JSON endpoint answers field for field as it did before it was typed.

``tests/fixtures/api-golden/answers.json`` holds what the API answered on
the store ``tests/fixtures/api-golden/store.sqlite`` when its handlers
returned plain dicts (made by ``python tests/api_golden.py`` before the
response models were written). The typed API must give the same JSON: a
field a response model forgets would vanish silently, a float field would
turn ``3`` into ``3.0``; both fail here.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from api_golden import ANSWERS, STORE, TOKENS, served, typed

from chaintwin.read.profile import load_profile
from chaintwin.store import migrate
from chaintwin.store.engine import engine_for
from chaintwin.store.store import Store
from chaintwin.web import create_app


def _differences(want: object, got: object, where: str = "") -> list[str]:
    """Where ``got`` differs from ``want`` (paths into the JSON), at most a few."""
    if isinstance(want, dict) and isinstance(got, dict):
        out = [f"{where}.{k}: missing" for k in want if k not in got]
        out += [f"{where}.{k}: extra" for k in got if k not in want]
        for k in want:
            if k in got:
                out += _differences(want[k], got[k], f"{where}.{k}")
        return out
    if isinstance(want, list) and isinstance(got, list):
        if len(want) != len(got):
            return [f"{where}: {len(want)} items expected, {len(got)} given"]
        return [d for k, (w, g) in enumerate(zip(want, got, strict=True))
                for d in _differences(w, g, f"{where}[{k}]")]  # fmt: skip
    return [] if typed(want) == typed(got) else [f"{where}: {want!r} expected, {got!r} given"]


def _changed_on_purpose(answer: object) -> object:
    """An answer of the fixture with what changed on purpose since it was captured.

    * the store's revision is the newest one (``GET /api/v1/health``);
    * a profile has ``zero_tracking`` (false unless the profile switches on
      zero tracking from known runs; the fixture's profiles do not).
    """
    if isinstance(answer, dict):
        body = answer.get("json")
        if isinstance(body, dict):
            store = body.get("store")
            if isinstance(store, dict) and "revision" in store:
                store["revision"] = migrate.HEAD_REVISION
            profile = body.get("profile")
            if isinstance(profile, dict):
                profile.setdefault("zero_tracking", False)
    return answer


def test_every_endpoint_answers_as_before(tmp_path: Path) -> None:
    store_file = tmp_path / "store.sqlite"
    shutil.copyfile(STORE, store_file)
    engine = engine_for(f"sqlite:///{store_file}")
    try:
        migrate.upgrade(engine)  # a store of an older revision, as a user's would be
    finally:
        engine.dispose()
    want = {k: _changed_on_purpose(a) for k, a in json.loads(ANSWERS.read_text()).items()}
    tokens = json.loads(TOKENS.read_text())
    got = served(store_file, tokens, None, create_app, Store, load_profile)
    assert sorted(got) == sorted(want), "the requests changed: run tests/api_golden.py again"
    wrong = {key: d[:5] for key in want if (d := _differences(want[key], got[key]))}
    assert not wrong, json.dumps(wrong, indent=1)
    statuses = [a["status"] for a in want.values()]
    assert statuses.count(200) >= len(statuses) - 2, "the fixture holds mostly refusals"
