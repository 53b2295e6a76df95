"""The station's live pages agree with their snapshots by construction, and this checks it.

A live page carries its stream's URL (``data-live``), made from the one table of live views
(``web/live.py``) that each page's router fills beside its route; ``static/station.js``
applies a snapshot by its fields. So for every live page, on a real station database and
the real application: the URL names a registered view, every element the page binds
(``data-bind``/``data-paint``) names a field of that view's snapshot, and every structured
field of the snapshot (a list or a map) has a drawing function in ``station.js``.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from html import unescape
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import pytest
from fastapi.testclient import TestClient

from blackbox.health.ids import robot_resource_id
from blackbox.station.auth import Role
from blackbox.station.store import StationStore
from blackbox.station.web.app import create_app
from blackbox.station.web.live import LiveViews, StreamQuery, UnknownLiveView
from station_support import Unreachable, quick_auth
from test_station_web_http import log_in

STATION_JS = Path(__file__).resolve().parent.parent / "src" / "blackbox" / "station" / \
    "web" / "static" / "station.js"
PASSWORD = "station password 1"


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[TestClient, list[str]]]:
    """The application and its live pages (fleet, robot, entity, a log request, a test)."""
    path = tmp_path / "station.db"
    store = StationStore.open(path)
    auth = quick_auth(path)
    auth.add_user("otto", PASSWORD, Role.OPERATOR)
    rid = robot_resource_id("bot")
    now = time.time()
    store.heard(rid, now)
    store.put_robot_id(rid, "bot")
    store.put_entity(rid, 1, name="bot", kind="robot", status="DEGRADED")
    store.put_entity(rid, 2, name="/cam", kind="node", parent=1, status="NOT_OPERATIONAL")
    store.put_characteristic(rid, 10, entity=2, name="rate", unit="Hz")
    store.put_value(rid, 10, now, 3.0)
    store.add_event(rid, now, "failure", dedup="f1", entity="/cam", text="/cam stopped")
    assert store.flush(force=True)
    log = store.create_log_request(rid, "bot", entity=None, characteristic=None, since=None,
                                   until=None, kinds=(), requested_by="otto")
    run = store.create_ibit_run(rid, "bot", "/cam", "otto")
    with TestClient(create_app(auth, store, Unreachable()),
                    base_url="http://127.0.0.1") as c:
        assert log_in(c, "otto", PASSWORD) == 303
        yield c, ["/", "/robot?r=bot", "/entity?r=bot&id=2", f"/logs/{log}", f"/ibit/{run}"]
    auth.close()
    store.close()


def drawing_functions() -> set[str]:
    """The field names of the ``parts`` table in station.js."""
    text = STATION_JS.read_text(encoding="utf-8")
    table = text[text.index("const parts = {"):text.index("function apply(")]
    return set(re.findall(r"^    (\w+): function", table, flags=re.M))


def test_every_live_page_binds_only_fields_its_snapshot_has_and_each_list_is_drawn(
        served: tuple[TestClient, list[str]]) -> None:
    client, pages = served
    live: LiveViews = client.app.state.live  # type: ignore[attr-defined]
    parts = drawing_functions()
    assert {"counts", "rows", "events", "entities", "values"} <= parts
    views = set()
    for page in pages:
        html = client.get(page).text
        found = re.search(r'data-live="([^"]+)"', html)
        assert found, f"{page} has no live root"
        url = urlsplit(unescape(found.group(1)))
        assert url.path == "/api/stream", (page, url)
        query = {k: v[0] for k, v in parse_qs(url.query).items()}
        views.add(query["view"])
        snapshot = live.snapshot(query["view"], StreamQuery(query.get("r", ""),
                                                            int(query.get("id", 0))))()
        assert snapshot, f"{page}: the snapshot of {query} is empty"
        bound = set(re.findall(r'data-(?:bind|paint)="([^"]+)"', html))
        assert bound <= set(snapshot), f"{page} binds fields its snapshot lacks: " \
            f"{sorted(bound - set(snapshot))}"
        structured = {k for k, v in snapshot.items() if isinstance(v, (dict, list))}
        assert structured <= parts, f"{page}: no drawing function in station.js for " \
            f"{sorted(structured - parts)}"
    assert views == set(live.names())  # every registered view has a page here


def test_a_page_cannot_name_a_view_no_router_registered() -> None:
    live = LiveViews()
    live.add("fleet", lambda query: dict)
    assert live.source("fleet") == "/api/stream?view=fleet"
    assert live.source("fleet", r="a b", id=3) == "/api/stream?view=fleet&r=a+b&id=3"
    with pytest.raises(UnknownLiveView):
        live.source("fleat")
    with pytest.raises(ValueError, match="registered twice"):
        live.add("fleet", lambda query: dict)


def test_the_stream_refuses_an_unknown_view(served: tuple[TestClient, list[str]]) -> None:
    client, _ = served
    reply = client.get("/api/stream?view=nothing")
    assert reply.status_code == 400 and "unknown view" in reply.text
