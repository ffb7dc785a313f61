// The operator page (operator_page.hpp): one self-contained document, no file read at
// run time and nothing fetched from elsewhere. It polls /api/state twice a second and
// asks for /view.jpg again as soon as the last one has loaded; text from the cell is set
// with textContent, never as HTML.
#include "markcell/host/operator_page.hpp"

namespace markcell::host {

const char* const kOperatorPageHtml = R"html(<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>markcell</title>
<style>
  body { font: 14px/1.35 system-ui, sans-serif; margin: 0; background: #f3f4f6; color: #111; }
  header { display: flex; align-items: center; gap: 16px; padding: 10px 16px; background: #1f2937; color: #fff; }
  header h1 { font-size: 18px; margin: 0; }
  #badge { padding: 3px 10px; border-radius: 4px; font-weight: 600; }
  .ok { background: #15803d; } .busy { background: #b45309; } .stop { background: #b91c1c; } .none { background: #6b7280; }
  #status { opacity: .85; }
  main { display: grid; grid-template-columns: minmax(0, 2fr) minmax(0, 1fr); gap: 12px; padding: 12px; }
  section { background: #fff; border-radius: 6px; padding: 10px 12px; box-shadow: 0 1px 2px rgba(0,0,0,.08); }
  h2 { font-size: 15px; margin: 0 0 8px; }
  #fault { display: none; background: #fee2e2; color: #7f1d1d; border: 1px solid #fca5a5; padding: 8px 12px; margin: 12px 12px 0; border-radius: 6px; font-weight: 600; }
  #view { width: 100%; background: #000; min-height: 120px; display: block; }
  table { border-collapse: collapse; width: 100%; font-size: 13px; }
  th, td { text-align: left; padding: 2px 6px; border-bottom: 1px solid #e5e7eb; white-space: nowrap; }
  td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
  .d-sprayed { color: #1d4ed8; } .d-marking { color: #c2410c; font-weight: 600; } .d-skipped { color: #6b7280; } .d-pending { color: #b91c1c; }
  .muted { color: #6b7280; }
  footer { padding: 0 16px 12px; color: #6b7280; font-size: 12px; }
</style>
</head>
<body>
<header>
  <h1 id="cell">markcell</h1>
  <span id="badge" class="none">connecting</span>
  <span id="status"></span>
</header>
<div id="fault"></div>
<main>
  <div>
    <section>
      <h2>Live view <span class="muted" id="view-note">(left | right: macro-features green, defects red / orange / blue when sprayed)</span></h2>
      <img id="view" alt="the newest tracked stereo pair">
    </section>
    <section style="margin-top:12px">
      <h2>Timing</h2>
      <table id="tasks"><thead><tr><th>task</th><th>lane</th><th class="num">budget µs</th><th class="num">p50 µs</th><th class="num">p99 µs</th><th class="num">max µs</th><th class="num">use %</th><th class="num">overruns</th><th class="num">misses</th></tr></thead><tbody></tbody></table>
      <table id="lanes" style="margin-top:8px"><thead><tr><th>lane</th><th class="num">ticks</th><th class="num">wake p50 µs</th><th class="num">wake p99 µs</th><th class="num">wake max µs</th><th class="num">missed</th></tr></thead><tbody></tbody></table>
    </section>
  </div>
  <div>
    <section>
      <h2>Panel</h2>
      <div><span id="panel-id" class="muted">no panel yet</span> <span id="panel-type" class="muted"></span></div>
      <div>marking: <b id="marking-state">-</b></div>
      <table id="defects" style="margin-top:6px"><thead><tr><th>defect</th><th>state</th><th>reason</th></tr></thead><tbody></tbody></table>
    </section>
    <section style="margin-top:12px">
      <h2>Last results</h2>
      <table id="results"><thead><tr><th>finished (UTC)</th><th>panel</th><th>result</th><th class="num">sprayed</th><th>reason</th></tr></thead><tbody></tbody></table>
    </section>
    <section style="margin-top:12px">
      <h2>Counts</h2>
      <div id="counts" class="muted"></div>
    </section>
    <section style="margin-top:12px">
      <h2>Faults</h2>
      <table id="faults"><thead><tr><th>time (UTC)</th><th>code</th><th>source</th><th>detail</th></tr></thead><tbody></tbody></table>
    </section>
  </div>
</main>
<footer>updated <span id="updates">0</span> times · <span id="version"></span> · read-only</footer>
<script>
"use strict";
const $ = (id) => document.getElementById(id);
let updates = 0;
function cell(tr, text, cls) { const td = document.createElement("td"); td.textContent = text; if (cls) td.className = cls; tr.appendChild(td); }
function fill(id, rows, make) {
  const body = $(id).tBodies[0];
  const fresh = document.createElement("tbody");
  for (const r of rows) { const tr = document.createElement("tr"); make(tr, r); fresh.appendChild(tr); }
  body.replaceWith(fresh);
}
function show(s) {
  $("cell").textContent = "markcell · " + s.cell;
  document.title = "markcell · " + s.cell;
  $("version").textContent = "markcell " + s.version + " (" + s.commit + "), up " + s.uptime_s.toFixed(0) + " s";
  $("status").textContent = s.status;
  const m = s.marking;
  const badge = $("badge");
  if (s.safe_stop.active) { badge.textContent = "safe stop"; badge.className = "stop"; }
  else if (m && m.on_panel) { badge.textContent = "marking"; badge.className = "busy"; }
  else { badge.textContent = "ready"; badge.className = "ok"; }
  const fault = $("fault");
  if (s.safe_stop.active) {
    fault.style.display = "block";
    fault.textContent = "Safe stop: " + s.safe_stop.code + " from " + s.safe_stop.source + ": " + s.safe_stop.detail;
  } else { fault.style.display = "none"; fault.textContent = ""; }
  if (m) {
    $("panel-id").textContent = m.panel ? (m.on_panel ? "panel " : "last panel ") + m.panel_id : "no panel yet";
    $("panel-type").textContent = m.panel ? "(" + m.panel_type + ")" : "";
    $("marking-state").textContent = m.state;
    fill("defects", m.defects, (tr, d) => { cell(tr, "D" + d.id); cell(tr, d.state, "d-" + d.state); cell(tr, d.reason || ""); });
  }
  fill("results", s.results, (tr, r) => {
    const sprayed = (r.defects || []).filter((d) => d.sprayed).length;
    cell(tr, (r.finished_utc || r.utc || "").slice(11, 23)); cell(tr, r.panel_id || ""); cell(tr, r.fault ? "fault" : "done", r.fault ? "d-pending" : "d-sprayed");
    cell(tr, r.defects ? sprayed + " of " + r.defects.length : "", "num"); cell(tr, r.reason || "");
  });
  const c = s.counts;
  $("counts").textContent = "panels done " + c.panels_done + ", fault " + c.panels_fault + "; defects sprayed " + c.defects_sprayed +
    ", skipped " + c.defects_skipped + "; records accepted " + c.records_accepted + ", rejected " + c.records_rejected +
    (s.vision ? "; frames " + s.vision.frames + ", dropped " + s.vision.dropped : "");
  fill("tasks", s.timing.tasks, (tr, t) => {
    cell(tr, t.name); cell(tr, t.lane); cell(tr, t.budget_us, "num"); cell(tr, t.p50_us, "num"); cell(tr, t.p99_us, "num");
    cell(tr, t.max_us, "num"); cell(tr, t.use_pct, "num"); cell(tr, t.overruns, "num"); cell(tr, t.misses, "num");
  });
  fill("lanes", s.timing.lanes, (tr, l) => {
    cell(tr, l.name); cell(tr, l.ticks, "num"); cell(tr, l.wake_p50_us, "num"); cell(tr, l.wake_p99_us, "num");
    cell(tr, l.wake_max_us, "num"); cell(tr, l.missed, "num");
  });
  fill("faults", s.faults.slice(0, 12), (tr, f) => { cell(tr, f.utc.slice(11, 23)); cell(tr, f.code); cell(tr, f.source); cell(tr, f.detail); });
  $("updates").textContent = String(++updates);
}
async function poll() {
  try {
    const r = await fetch("/api/state", { cache: "no-store" });
    if (r.ok) show(await r.json());
  } catch (e) {
    $("badge").textContent = "no connection"; $("badge").className = "none";
  }
  setTimeout(poll, 500);
}
let views = 0;
const view = $("view");
function nextView(delay) { setTimeout(() => { view.src = "/view.jpg?n=" + (++views); }, delay); }
view.addEventListener("load", () => nextView(150));
view.addEventListener("error", () => nextView(1000));
poll();
nextView(0);
</script>
</body>
</html>
)html";

}  // namespace markcell::host
