// Live updates for the station's pages: one Server-Sent Events stream per page, no reloads.
// Robot-supplied text is only ever written with textContent.
"use strict";
(function () {
  const HEALTH = ["h-operational", "h-degraded", "h-not-operational", "h-unknown"];
  function healthClass(status) {
    return "h-" + String(status || "UNKNOWN").toLowerCase().replace(/_/g, "-");
  }
  function paint(el, status) {
    if (!el) return;
    HEALTH.forEach(function (c) { el.classList.remove(c); });
    el.classList.add(healthClass(status));
  }
  function setText(el, text) { if (el) el.textContent = text == null ? "" : String(text); }

  function cell(text) { const td = document.createElement("td"); td.textContent = text; return td; }
  function ackForm(ev, back) {
    const form = document.createElement("form");
    form.method = "post"; form.action = "/ack"; form.className = "inline";
    [["csrf_token", document.body.dataset.csrf], ["event", ev.id], ["robot", ev.robot],
     ["back", back]].forEach(function (kv) {
      const input = document.createElement("input");
      input.type = "hidden"; input.name = kv[0]; input.value = String(kv[1]);
      form.appendChild(input);
    });
    const button = document.createElement("button");
    button.type = "submit"; button.className = "small"; button.textContent = "Acknowledge";
    form.appendChild(button);
    return form;
  }
  function el(tag, className, text) {
    const node = document.createElement(tag);
    if (className) node.className = className;
    if (text != null) node.textContent = String(text);
    return node;
  }
  function clipped(tag, className, text) {
    const node = el(tag, "clip " + (className || ""), text); node.title = String(text || ""); return node;
  }
  function evidenceList(evidence) {
    const dl = el("dl");
    (evidence || []).forEach(function (e) {
      dl.appendChild(el("dt", "", e.label));
      (e.items || []).forEach(function (item) { dl.appendChild(el("dd", "", item)); });
    });
    return dl;
  }
  // The same markup as templates/_headline.html.
  function headlineBlock(h) {
    const div = el("div", "headline hl-" + h.severity);
    const p = el("p", "hl-text");
    p.appendChild(el("b", "", h.text));
    if (h.when) { p.appendChild(document.createTextNode(" ")); p.appendChild(el("span", "hl-when", "— " + h.when)); }
    if (h.certainty) { p.appendChild(document.createTextNode(" ")); p.appendChild(el("span", "hl-certainty", "(" + h.certainty + ")")); }
    div.appendChild(p);
    [["Operator:", h.operator_action], ["Maintenance:", h.maintenance_action]].forEach(function (a) {
      if (!a[1]) return;
      const line = el("p", "hl-action"); line.appendChild(el("b", "", a[0]));
      line.appendChild(document.createTextNode(" " + a[1])); div.appendChild(line);
    });
    if (h.evidence && h.evidence.length) {
      const details = el("details", "hl-evidence"); details.appendChild(el("summary", "", "Evidence"));
      details.appendChild(evidenceList(h.evidence)); div.appendChild(details);
    }
    return div;
  }
  // The same markup as the "What" cell of templates/_events.html.
  function whatCell(ev) {
    const td = el("td", "what");
    const h = ev.headline || { text: ev.text, evidence: [] };
    const details = el("details", "full");
    if (h.text !== ev.text || (h.evidence && h.evidence.length)) {
      const line = clipped("div", "ev-headline hl-" + h.severity, h.text);
      if (h.certainty) { line.appendChild(document.createTextNode(" ")); line.appendChild(el("span", "hl-certainty", "(" + h.certainty + ")")); }
      td.appendChild(line);
      if (h.operator_action) {
        const action = clipped("div", "hl-action", ""); action.title = h.operator_action;
        action.appendChild(el("b", "", "Operator:")); action.appendChild(document.createTextNode(" " + h.operator_action));
        td.appendChild(action);
      }
      details.appendChild(el("summary", "", "Details"));
      if (h.evidence && h.evidence.length) details.appendChild(evidenceList(h.evidence));
    } else {
      details.appendChild(clipped("summary", "", ev.text));
    }
    details.appendChild(el("p", "", ev.text));
    td.appendChild(details);
    return td;
  }
  function renderEvents(table, events) {
    if (!table) return;
    const operator = ["operator", "admin"].indexOf(document.body.dataset.role) >= 0;
    const body = table.tBodies[0];
    if (!events.length) return;
    const open = new Set(Array.from(body.querySelectorAll("tr[data-event] details[open]"))
      .map(function (d) { return d.closest("tr").dataset.event; }));
    body.replaceChildren.apply(body, events.map(function (ev) {
      const tr = document.createElement("tr");
      tr.className = "ev-" + ev.kind;
      tr.dataset.event = String(ev.id);
      const kind = clipped("td", "", ev.kind + (ev.origin !== "live" ? " (" + ev.origin + ")" : ""));
      [clipped("td", "", ev.clock || ev.time), clipped("td", "", ev.robot), clipped("td", "", ev.entity), kind, whatCell(ev)]
        .forEach(function (td) { tr.appendChild(td); });
      tr.firstChild.title = ev.time;
      if (open.has(String(ev.id))) tr.querySelector("details").open = true;  // keep what the operator opened
      const ack = clipped("td", "", ev.acknowledged_by || "");
      if (!ev.acknowledged_by && operator && (ev.kind === "failure" || ev.kind === "exceedance")) {
        ack.appendChild(ackForm(ev, table.dataset.back || "/events"));
      }
      tr.appendChild(ack);
      return tr;
    }));
  }
  function renderHeadlines(box, headlines) {
    if (!box || !headlines) return;
    // the same headlines again (most snapshots): leave the DOM alone, so a selection, an
    // opened evidence list and a reader's place survive the live updates
    const drawn = JSON.stringify(headlines);
    if (box.dataset.drawn === drawn) return;
    box.dataset.drawn = drawn;
    const open = Array.from(box.querySelectorAll(".headline")).map(function (d) {
      const ev = d.querySelector("details"); return !!(ev && ev.open);
    });
    box.replaceChildren.apply(box, headlines.map(function (h, i) {
      const block = headlineBlock(h);
      const details = block.querySelector("details");
      if (details && open[i]) details.open = true;
      return block;
    }));
  }

  let reloading = false;
  function reloadOnce() {
    // The page's structure changed (a new robot or entity, a finished log): render it anew.
    if (!reloading) { reloading = true; window.location.reload(); }
  }

  // How each structured field of a snapshot is drawn, whatever page it came from. Scalar
  // fields need nothing here: every element with data-bind="FIELD" shows the field's value
  // (data-empty when there is none) and every data-paint="FIELD" takes its health colour.
  // Which snapshot a page listens to is the server's business (web/live.py): the page's
  // data-live attribute is its stream's URL.
  const parts = {
    counts: function (counts) {
      Object.keys(counts || {}).forEach(function (status) {
        const a = document.querySelector('[data-count="' + CSS.escape(status) + '"] [data-field="count"]');
        setText(a, counts[status]);
      });
    },
    rows: function (rows) {
      // The server sends this page's rows in order (worst first): redraw them.
      const table = document.querySelector("table.fleet");
      const body = table && table.tBodies[0];
      if (!body || !rows) return;
      body.replaceChildren.apply(body, rows.map(function (r) {
        const tr = document.createElement("tr");
        tr.dataset.robot = r.ref;
        const name = el("td"); const link = el("a", "", r.name);
        link.href = "/robot?r=" + encodeURIComponent(r.ref); name.appendChild(link);
        const status = el("td"); const badge = el("span", "badge " + healthClass(r.status), r.status);
        badge.dataset.field = "status"; status.appendChild(badge);
        status.appendChild(document.createTextNode(" "));
        const silent = el("small", "muted", r.silent); silent.dataset.field = "silent"; status.appendChild(silent);
        const fields = [["site", r.site], ["diagnosis", r.diagnosis], ["entities", r.entities],
          ["failing", r.failing], ["unacknowledged", r.unacknowledged], ["last_heard", r.last_heard]]
          .map(function (f) { const td = el("td", "", f[1]); td.dataset.field = f[0]; return td; });
        [name, fields[0], status].concat(fields.slice(1)).forEach(function (td) { tr.appendChild(td); });
        return tr;
      }));
    },
    diagnosis: function (components) {
      const comp = document.getElementById("diagnosis-components");
      if (!comp) return;
      setText(comp, components || "none");
      comp.className = components ? "bad" : "good";
    },
    headlines: function (headlines) { renderHeadlines(document.getElementById("headlines"), headlines); },
    events: function (events) { renderEvents(document.querySelector("table.events"), events || []); },
    entities: function (entities) {
      Object.keys(entities || {}).forEach(function (id) {
        const li = document.querySelector('li[data-entity="' + CSS.escape(id) + '"]');
        if (!li) { reloadOnce(); return; }  // the robot described a new entity
        paint(li, entities[id]);
        setText(li.querySelector('[data-field="status"]'), entities[id]);
      });
    },
    values: function (values) {
      Object.keys(values || {}).forEach(function (id) {
        const v = values[id];
        const row = document.querySelector('tr[data-char="' + CSS.escape(id) + '"]');
        if (row) {
          setText(row.querySelector('[data-field="value"]'),
                  v[1] == null ? "-" : Number(v[1]).toPrecision(4).replace(/\.?0+$/, ""));
          row.classList.toggle("exceeded", !!v[2]);
        }
        if (window.stationCharts && v[0] != null && v[1] != null) window.stationCharts.add(id, v[0], v[1]);
      });
    },
    report: function (report) {
      const ul = document.getElementById("ibit-report");
      if (!ul) return;
      ul.replaceChildren.apply(ul, (report || []).map(function (line) {
        const li = document.createElement("li"); li.textContent = line; return li;
      }));
    },
    progress: function (progress, s) {
      const bar = document.getElementById("log-progress");
      if (!bar) return;
      bar.value = progress || 0;
      const done = s.status !== "pending" && s.status !== "running";
      const downloads = document.getElementById("log-downloads");
      if (done && downloads.classList.contains("hidden") && s.rows > 0 &&
          !document.getElementById("log-preview")) reloadOnce();  // show the first rows
      downloads.classList.toggle("hidden", !done);
    },
  };
  function apply(s) {
    Object.keys(s).forEach(function (field) {
      const value = s[field];
      if (parts[field]) { parts[field](value, s); return; }
      document.querySelectorAll('[data-bind="' + field + '"]').forEach(function (node) {
        setText(node, value == null || value === "" ? (node.dataset.empty || "") : value);
      });
      document.querySelectorAll('[data-paint="' + field + '"]').forEach(function (node) {
        paint(node, value || "UNKNOWN");
      });
    });
  }

  const root = document.querySelector("[data-live^='/api/stream']");
  if (!root || !window.EventSource) return;
  const source = new EventSource(root.dataset.live);
  source.addEventListener("state", function (e) {
    const state = JSON.parse(e.data);
    if (Object.keys(state).length) apply(state);
    document.dispatchEvent(new CustomEvent("station:state"));  // e.g. the timeline redraws
    document.body.dataset.updated = String(Date.now());
  });
  source.addEventListener("end", function () { source.close(); });
  source.onopen = function () { document.body.classList.remove("offline"); document.body.dataset.live = "open"; };
  source.onerror = function () { document.body.classList.add("offline"); };
})();
