/* chaintwin dashboard: charts from the JSON API (Plotly, served locally), live fleet table. */
"use strict";
window.chaintwin = (function () {
  const csrf = () => document.querySelector('meta[name="csrf-token"]').content;

  async function api(path) {
    const r = await fetch(path, { credentials: "same-origin", headers: { "X-CSRF-Token": csrf() } });
    if (r.status === 401) { window.location = "/login"; return null; }
    if (!r.ok) { throw new Error((await r.json()).error.message); }
    return r.json();
  }

  function text(value, digits) {
    return value === null || value === undefined ? "\u2013" : Number(value).toFixed(digits);
  }

  function health(row) {
    return row.health;
  }

  function sortable(table) {
    table.querySelectorAll("th").forEach((th, col) => {
      th.addEventListener("click", () => {
        const body = table.tBodies[0];
        const rows = Array.from(body.rows);
        const num = th.hasAttribute("data-num");
        const dir = th.dataset.dir === "asc" ? -1 : 1;
        th.dataset.dir = dir === 1 ? "asc" : "desc";
        rows.sort((a, b) => {
          const x = a.cells[col].textContent, y = b.cells[col].textContent;
          if (num) return dir * ((parseFloat(x) || -Infinity) - (parseFloat(y) || -Infinity));
          return dir * x.localeCompare(y);
        });
        rows.forEach((r) => body.appendChild(r));
      });
    });
  }

  function healthChart(rows) {
    const have = rows.filter((r) => r.health_index !== null)
      .sort((a, b) => b.health_index - a.health_index);
    Plotly.react("health-chart", [{ type: "bar", x: have.map((r) => r.id), y: have.map((r) => r.health_index),
      text: have.map((r) => r.worst_feature || ""), hovertemplate: "%{x}: %{y:.2f} (%{text})<extra></extra>",
      marker: { color: have.map((r) => (r.health_index >= 1 ? "#c0392b" : r.health_index >= 0.7 ? "#e67e22" : "#27ae60")) } }],
      { margin: { t: 10 }, yaxis: { title: "health index" },
        shapes: [{ type: "line", xref: "paper", x0: 0, x1: 1, y0: 1, y1: 1, line: { dash: "dash", color: "#c0392b" } }] },
      { responsive: true });
  }

  // A chart with nothing to draw is said in words instead (never an empty chart).
  function absent(div, text) {
    Plotly.purge(div);
    div.classList.add("absent");
    div.textContent = text;
  }

  function present(div) {
    if (div.classList.contains("absent")) { div.classList.remove("absent"); div.textContent = ""; }
  }

  // The words under a chart for what it leaves out (hidden when nothing is).
  function leftOut(div, text) {
    let p = div.nextElementSibling;
    if (!p || !p.classList.contains("left-out")) {
      p = document.createElement("p");
      p.className = "hint left-out";
      div.after(p);
    }
    p.textContent = text;
    p.hidden = !text;
  }

  // Why a conveyor's latest recording has no TLF: f_T = W / (m_p g s) needs both.
  function noTlf(r) {
    if (r.last_recorded_at === null && r.status === null) return `${r.id} (no recording yet)`;
    if (r.payload_kg === null) return `${r.id} (its payload could not be weighed; see the recording's warnings)`;
    if (r.payload_kg < 1) return `${r.id} (payload under 1 kg: nearly empty)`;
    return `${r.id} (no belt travel)`;
  }

  function tlfChart(rows) {
    const div = document.getElementById("tlf-chart");
    const have = rows.filter((r) => r.tlf !== null).sort((a, b) => b.tlf - a.tlf);
    const without = rows.filter((r) => r.tlf === null).map(noTlf);
    if (!have.length) {
      absent(div, rows.length
        ? `No TLF to draw: no conveyor's latest recording has one. Not drawn: ${without.join("; ")}.`
        : "No conveyors yet.");
      leftOut(div, "");
      return;
    }
    present(div);
    Plotly.react(div, [{ type: "bar", x: have.map((r) => r.id), y: have.map((r) => r.tlf) }],
      { margin: { t: 10 }, yaxis: { title: "TLF" } }, { responsive: true });
    leftOut(div, without.length ? `Not drawn, no TLF in the latest recording: ${without.join("; ")}.` : "");
  }

  // Refresh on the server's events (GET /api/v1/events); poll every 30 s if they cannot come.
  // The stream's first "ready" refreshes once: a change stored between the page's own
  // reads and the stream's start is sent by no event (later "ready"s are reconnects
  // with nothing changed; a change meanwhile comes as "update").
  function live(onUpdate) {
    let timer = null;
    const fallback = () => { if (timer === null) timer = setInterval(onUpdate, 30000); };
    if (!window.EventSource) { fallback(); return; }
    const source = new EventSource("/api/v1/events");
    let first = true;
    source.addEventListener("ready", () => {
      window.chaintwin.connected = true;
      if (first) { first = false; onUpdate(null); }
    });
    source.addEventListener("update", (e) => {
      window.chaintwin.connected = true;
      window.chaintwin.updates += 1;
      onUpdate(JSON.parse(e.data));
    });
    source.onerror = () => { if (source.readyState === EventSource.CLOSED) fallback(); };
  }

  function fillRow(tr, row) {
    tr.querySelector(".health").textContent = health(row);
    tr.querySelector(".health").title = `NE 107 ${row.ne107}`;
    const index = tr.querySelector(".index");
    index.textContent = text(row.health_index, 2);
    index.title = row.worst_feature || "";
    tr.querySelector(".alarms").textContent =
      row.open_alarms.map((a) => `${a.cause} (${a.feature})`).join(", ");
    tr.querySelector(".payload").textContent = text(row.payload_kg, 1);
    tr.querySelector(".tlf").textContent = text(row.tlf, 3);
    tr.querySelector(".last").textContent = row.last_recorded_at || "\u2013";
  }

  function newRow(row) {
    // built from text nodes: an id holding markup stays text
    const tr = document.createElement("tr");
    tr.dataset.id = row.id;
    const first = document.createElement("td");
    const a = document.createElement("a");
    a.href = "/conveyors/" + encodeURIComponent(row.id);
    a.textContent = row.id;
    first.appendChild(a);
    tr.appendChild(first);
    ["health", "index", "alarms", "payload", "tlf", "last"].forEach((cls) => {
      const td = document.createElement("td");
      td.className = cls;
      tr.appendChild(td);
    });
    return tr;
  }

  async function fleetPage() {
    const table = document.getElementById("fleet");
    sortable(table);
    const filter = document.getElementById("filter");
    const applyFilter = () => {
      const q = filter.value.toLowerCase();
      Array.from(table.tBodies[0].rows).forEach((r) => {
        r.hidden = !r.textContent.toLowerCase().includes(q);
      });
    };
    filter.addEventListener("input", applyFilter);
    async function refresh() {
      const rows = await api("/api/v1/conveyors");
      if (!rows) return;
      const body = table.tBodies[0];
      const byId = new Map(Array.from(body.rows).map((r) => [r.dataset.id, r]));
      rows.forEach((row) => {
        let tr = byId.get(row.id);
        if (!tr) { tr = newRow(row); body.appendChild(tr); }
        fillRow(tr, row);
      });
      applyFilter();
      healthChart(rows);
      tlfChart(rows);
      document.getElementById("updated").textContent = new Date().toLocaleTimeString();
    }
    await refresh();
    live(refresh);
  }

  // One feature's trend drawn into its chart, in place (Plotly.react): a new
  // recording updates the chart without clearing it.
  function drawTrend(div, t) {
    const feature = t.feature;
    if (!t.points.some((p) => p.value !== null)) {
      absent(div, `${feature}: no value to draw yet (${t.recordings} recording(s), none with this feature).`);
      return;
    }
    present(div);
    const x = t.points.map((p) => p.recorded_at);
    const traces = [{ x, y: t.points.map((p) => p.value), mode: "lines+markers", name: feature,
      marker: { color: t.points.map((p) => (p.exceeded ? "#c0392b" : "#2c3e50")), size: 5 } }];
    const shapes = [];
    if (t.expected !== null && t.limit !== null && x.length) {
      traces.push({ x: [x[0], x[x.length - 1]], y: [t.limit, t.limit], mode: "lines",
        name: "alarm limit", line: { dash: "dash", color: "#c0392b" } });
      shapes.push({ type: "rect", xref: "paper", x0: 0, x1: 1, y0: t.expected, y1: t.limit,
        fillcolor: "rgba(46, 204, 113, 0.12)", line: { width: 0 } });
    }
    const f = t.forecast;
    if (f && f.band && f.band.at.length) {
      // the forecast's 90 % band (upper, then lower filled to it), its mean, and its crossings
      const b = f.band;
      const pct = Math.round(100 * b.level);
      traces.push({ x: b.at, y: b.upper, mode: "lines", line: { width: 0 }, hoverinfo: "skip",
        name: `${pct} % band` });
      traces.push({ x: b.at, y: b.lower, mode: "lines", line: { width: 0 }, fill: "tonexty",
        fillcolor: "rgba(230, 126, 34, 0.25)", name: `forecast ${pct} % band (${f.model})` });
      traces.push({ x: b.at, y: b.mean, mode: "lines", line: { dash: "dot", color: "#e67e22" },
        name: "forecast" });
      traces.push({ x: [b.at[0], b.at[b.at.length - 1]], y: [f.limit, f.limit], mode: "lines",
        line: { dash: "dash", color: "#c0392b" }, name: "alarm limit", showlegend: false });
      [["earliest", f.earliest], ["crosses", f.crosses_at], ["latest", f.latest]].forEach(([n, at]) => {
        if (at) shapes.push({ type: "line", x0: at, x1: at, yref: "paper", y0: 0, y1: 1,
          line: { color: "#e67e22", width: 1, dash: n === "crosses" ? "solid" : "dot" } });
      });
    }
    t.alarms.forEach((a) => {
      if (a.since) shapes.push({ type: "line", x0: a.since, x1: a.since, yref: "paper", y0: 0, y1: 1,
        line: { color: "#c0392b", width: 1 } });
    });
    Plotly.react(div, traces, { title: { text: `${feature} (${t.unit}) \u2192 ${t.cause || "tracked"}` },
      margin: { t: 40 }, shapes, height: 260, showlegend: false, datarevision: t.recordings },
      { responsive: true });
  }

  // Every trend of the conveyor in one request; each chart made once and then updated in place.
  async function trendCharts(holder, conveyor, features) {
    if (!features.length) return;
    const all = await api(`/api/v1/conveyors/${encodeURIComponent(conveyor)}/trends`);
    if (!all) return;
    const charts = new Map(Array.from(holder.querySelectorAll("div.chart.trend")).map((d) => [d.dataset.feature, d]));
    all.trends.forEach((t) => {
      let div = charts.get(t.feature);
      if (!div) {
        div = document.createElement("div");
        div.className = "chart trend";
        div.dataset.feature = t.feature;
        holder.appendChild(div);
      }
      drawTrend(div, t);
    });
  }

  // the verdict line of a conveyor's page, from the fleet's rows (cheap: one snapshot)
  async function showVerdict(conveyor) {
    const rows = await api("/api/v1/conveyors");
    const row = rows && rows.find((r) => r.id === conveyor);
    if (!row) return;
    const since = (at) => (at ? ` since ${at.slice(0, 16)}` : "");
    const set = (sel, value) => { const el = document.querySelector(sel); if (el) el.textContent = value; };
    set("strong.health", row.health);
    set(".health-since", since(row.health_since));
    set("strong.ne107", row.ne107);
    set(".ne107-since", since(row.ne107_since));
  }

  async function conveyorPage() {
    const holder = document.getElementById("trends");
    const conveyor = holder.dataset.conveyor;
    const features = JSON.parse(holder.dataset.features);
    const newest = async () => {
      const p = await api(`/api/v1/conveyors/${encodeURIComponent(conveyor)}/recordings?limit=1`);
      return p && p.items.length ? p.items[0].recording_id : null;
    };
    let shown = await newest();
    // listen before drawing: the verdict follows a change made while the trends are drawn
    let drawing = drawConveyor(holder, conveyor, features);
    // update the charts in place when a new recording of this conveyor is stored
    live(async () => {
      await showVerdict(conveyor);
      await drawing;
      const now = await newest();
      if (now !== shown) {
        shown = now;
        drawing = drawConveyor(holder, conveyor, features);
        await drawing;
      }
    });
    await drawing;
  }

  async function waterfallChart(conveyor) {
    const w = await api(`/api/v1/conveyors/${encodeURIComponent(conveyor)}/waterfall?recordings=20`);
    const div = document.getElementById("waterfall");
    if (!w || !w.recordings.length) { div.textContent = "No spectra yet."; return; }
    const y = w.recordings.map((r, k) =>
      r.recorded_at ? `${r.recorded_at.slice(0, 16).replace("T", " ")} #${k + 1}` : `#${k + 1} ${r.file}`);
    const z = w.amplitude_nm.map((row) => row.map((a) => (a && a > 0 ? Math.log10(a) : null)));
    const shapes = Object.entries(w.lines).map(([name, x]) => ({ type: "line", x0: x, x1: x,
      yref: "paper", y0: 0, y1: 1, line: { color: "white", width: 1, dash: "dash" } }));
    const notes = Object.entries(w.lines).map(([name, x]) => ({ x, y: 1, yref: "paper",
      text: name.replace(/_/g, " "), showarrow: false, textangle: -90, font: { size: 9, color: "#fff" },
      xanchor: "right", yanchor: "top" }));
    Plotly.react(div, [{ type: "heatmap", x: w.x, y, z, colorscale: "Viridis",
      colorbar: { title: { text: "log10 Nm" } },
      hovertemplate: "%{x:.2f}: %{customdata:.3g} Nm<extra>%{y}</extra>",
      customdata: w.amplitude_nm }],
      { margin: { t: 10, l: 140 }, height: 380, shapes, annotations: notes,
        xaxis: { title: w.x_unit }, yaxis: { type: "category" } }, { responsive: true });
  }

  async function drawConveyor(holder, conveyor, features) {
    await trendCharts(holder, conveyor, features);
    await waterfallChart(conveyor);
    const page = await api(`/api/v1/conveyors/${encodeURIComponent(conveyor)}/recordings?limit=1000`);
    const payloads = page.items.map((r) => r.payload_kg).filter((p) => p !== null);
    const histogram = document.getElementById("payloads");
    if (!payloads.length) {
      absent(histogram, page.items.length
        ? `No payload to draw: none of its latest ${page.items.length} recordings could be weighed (each recording's warnings say why).`
        : "No recordings yet.");
    } else {
      present(histogram);
      Plotly.react(histogram, [{ type: "histogram", x: payloads }],
        { margin: { t: 10 }, xaxis: { title: "payload kg" }, height: 260 }, { responsive: true });
      const unweighed = page.items.length - payloads.length;
      leftOut(histogram, unweighed
        ? `${unweighed} of the latest ${page.items.length} recordings could not be weighed and are not counted (each recording's warnings say why).`
        : "");
    }
    if (page.items.length) {
      const rec = await api(`/api/v1/recordings/${page.items[0].recording_id}`);
      const s = rec.series;
      const traces = [{ x: s.time_s, y: s.torque_nm, name: "measured torque" }];
      if (s.model_torque_nm) traces.push({ x: s.time_s, y: s.model_torque_nm, name: "model torque" });
      traces.push({ x: s.time_s, y: s.speed_rpm, name: "speed rpm", yaxis: "y2" });
      Plotly.react("latest", traces, { margin: { t: 10 }, height: 320,
        xaxis: { title: "s" }, yaxis: { title: "Nm" },
        yaxis2: { title: "rpm", overlaying: "y", side: "right" } }, { responsive: true });
    }
  }

  // The alarm list: its rows again from the server (rendered and escaped there) on each
  // update, but for the one a maintainer is working in.
  function alarmsPage() {
    // each conveyor form posts to its conveyor's address (no inline handler: the CSP
    // allows none)
    ["maintenance", "out-of-service", "in-service"].forEach((id) => {
      const form = document.getElementById(id);
      if (!form) return;
      form.addEventListener("submit", () => {
        form.action = "/conveyors/" + encodeURIComponent(form.conveyor.value) + "/" + id;
      });
    });
    const body = document.querySelector("table.alarms tbody");
    // The row a maintainer is working in (a field focused or filled in, a button pressed)
    // stays as it is, the others are replaced: a reason being typed is never lost, and a
    // list left open with a field focused still follows the plant.
    let pressed = null;
    body.addEventListener("pointerdown", (e) => { pressed = e.target.closest("tr"); });
    ["pointerup", "pointercancel"].forEach((t) => window.addEventListener(t, () => { pressed = null; }));
    const busy = () => Array.from(body.rows).find((tr) =>
      tr === pressed || tr.contains(document.activeElement) ||
      Array.from(tr.querySelectorAll("input:not([type=hidden])")).some((i) => i.value));
    live(async () => {
      const r = await fetch("/alarms", { credentials: "same-origin" });
      if (r.status === 401 || r.redirected) { window.location = "/login"; return; }
      if (!r.ok) return;
      const page = new DOMParser().parseFromString(await r.text(), "text/html");
      const fresh = page.querySelector("table.alarms tbody");
      if (!fresh) return;
      const rows = Array.from(fresh.rows).map((n) => document.adoptNode(n));
      const keep = busy();  // asked when the answer is in, not before the request
      if (!keep) { body.replaceChildren(...rows); return; }
      const at = rows.findIndex((tr) => tr.dataset.alarm === keep.dataset.alarm);
      if (at < 0) return;  // its alarm left the list meanwhile: the rest waits until done
      // the kept row is never taken out (that would blur a focused field)
      Array.from(body.childNodes).forEach((n) => { if (n !== keep) n.remove(); });
      rows.slice(0, at).forEach((tr) => body.insertBefore(tr, keep));
      body.append(...rows.slice(at + 1));
    });
  }

  return { fleetPage, conveyorPage, alarmsPage, updates: 0, connected: false };
})();

// The page names what it runs on the script element (data-page): no inline script.
(function () {
  const page = document.currentScript && document.currentScript.dataset.page;
  if (page) window.chaintwin[page + "Page"]();
})();
