// The operator page: everything the station pushes over /events (server-sent events) drawn
// at once; commands posted to /api/command with their answers inline. No framework: the
// page is small, and the station serves it offline.
"use strict";

const $ = (id) => document.getElementById(id);
const state = {snap: null, cards: new Map(), rev: 0, authorized: false, token: "", selected: null,
  follow: true, received: 0, answers: new Map(), waiting: new Map(), newest: null, thumbsHeld: true,
  asked: null};  // asked: the chosen capture's request, aborted when another is chosen
const THUMBS_HELD_MS = 2000;  // the cards' pictures wait at most this long for the chosen capture's
window.btfPage = {shown: {}, hello: 0};  // when each capture ("robot:seq") was first drawn (benchmarks)

function esc(s) {
  return String(s ?? "").replace(/[&<>"']/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]));
}
const deg = (v) => (v === null || v === undefined ? "?" : `${Number(v).toFixed(1)}°`);
// an azimuth in [0, 360) as shown: 359.96 is 0.0°, never 360.0°
const azDeg = (v) => (v === null || v === undefined ? "?" : deg(((Math.round(Number(v) * 10) / 10) % 360 + 360) % 360));
const pose = (p) => (p ? `${deg(p.elevation)} / ${azDeg(p.azimuth)}` : "unknown");
function ago(s) {
  if (s === null || s === undefined) return "never";
  return s < 60 ? `${s.toFixed(1)} s ago` : s < 3600 ? `${Math.floor(s / 60)} min ${Math.round(s % 60)} s ago` : `${(s / 3600).toFixed(1)} h ago`;
}
function bytes(n) {
  if (n === null || n === undefined) return "?";
  const u = ["B", "kB", "MB", "GB", "TB"];
  let i = 0;
  while (n >= 1000 && i < u.length - 1) { n /= 1000; i++; }
  return `${n.toFixed(i ? 1 : 0)} ${u[i]}`;
}
const clock = (iso) => (iso ? iso.slice(11, 19) : "");
function rows(table, list) {
  table.innerHTML = list.filter(Boolean).map(([k, v, cls]) =>
    `<tr><th>${esc(k)}</th><td${cls ? ` class=${cls}` : ""}>${v}</td></tr>`).join("");
}
function badge(el, text, cls) {
  el.textContent = text;
  el.className = `badge ${cls}`;
}

// -- the link and the robot ------------------------------------------------------------------
function heardText() {
  const l = state.snap && state.snap.link;
  if (!l || l.last_heard_s === null) return "robot never heard";
  return `heard ${ago(l.last_heard_s + (Date.now() - state.received) / 1000)}`;
}

function drawLink(s) {
  const l = s.link, r = s.robot;
  badge($("link-badge"), l.up ? "link up" : "link down", l.up ? "ok" : "bad");
  $("heard").textContent = heardText();
  const rejected = Object.entries(l.rejected || {});
  const total = rejected.reduce((a, [, n]) => a + n, 0);
  const resent = l.frames_sent ? (100 * l.retransmissions / l.frames_sent).toFixed(1) : "0.0";
  const refused = l.frames_accepted + total ? (100 * total / (l.frames_accepted + total)).toFixed(1) : "0.0";
  const robotRejected = Object.entries(r.rejected || {});
  rows($("link-table"), [
    ["state", `${l.up ? "up" : "DOWN"}${l.changed ? ` since ${clock(l.changed)}` : ""}`, l.up ? "ok" : "bad"],
    ["last heard", `<span id=heard-cell>${esc(heardText())}</span>`],
    ["loss (resent / sent)", `${resent}% (${l.retransmissions} of ${l.frames_sent} frames)`,
      Number(resent) > 20 ? "warn" : ""],
    ["refused frames", `${refused}% (${total})` + (rejected.length ? "<br>" + rejected.map(([k, n]) =>
      `<span title="${esc(k)}">${esc(k)} ${n}</span>`).join(", ") : ""), total ? "warn" : ""],
    ["goodput", `${bytes(l.goodput_bps)}/s (last 10 s)`],
    ["delivered", `${l.delivered} messages, ${bytes(l.delivered_bytes)}; ${l.duplicates} duplicates`],
    ["robot's outbox", r.outbox === null ? "?" : `${r.outbox} waiting`, r.outbox > 20 ? "warn" : ""],
    ["robot's disk", r.disk === null ? "not reported (ok)" : `${esc(r.disk)}${r.disk_free !== null ? `, ${bytes(r.disk_free)} free` : ""}`,
      r.disk && r.disk !== "ok" ? "bad" : ""],
    robotRejected.length ? ["robot refused", robotRejected.map(([k, n]) => `${esc(k)} ${n}`).join(", "), "warn"] : null,
  ]);
}

function modeOf(s) {
  const r = s.robot;
  if (r.failsafe_assumed) return ["failsafe", "bad", `assumed: the link has been silent past the robot's failsafe (${r.failsafe_s ?? 5} s); it reports when the link returns`];
  if (r.mode === "failsafe") return ["failsafe", "bad", "the robot holds the arm"];
  if (r.disk && r.disk !== "ok") return [`paused: disk ${r.disk}`, "warn", ""];
  if (r.paused) return [`paused`, "warn", r.paused];
  if (r.mode === "sweeping") return ["sweeping (autonomous)", "busy", ""];
  if (r.mode === "idle") return ["idle (remote)", "idle", "waiting for commands"];
  return [r.mode || "unknown", "unknown", "the robot has not reported yet"];
}

function drawRobot(s) {
  const r = s.robot, [mode, cls, why] = modeOf(s);
  badge($("mode-badge"), mode, cls);
  $("mode-badge").title = why;
  rows($("robot-table"), [
    ["mode", `${esc(mode)}${why ? `<br><span class=note>${esc(why)}</span>` : ""}`, cls === "bad" ? "bad" : ""],
    ["robot", r.id === null ? "?" : `${r.id}`],
    ["pose measured", pose(r.pose)],
    ["pose commanded", pose(r.commanded)],
    ["torque", r.torque === null ? "?" : r.torque ? "on" : "OFF (torque-on holds the arm)", r.torque === false ? "warn" : ""],
    ["last report", `${ago(r.last_status_s)}${r.last_status_text && r.last_status_text !== "status" ? `: ${esc(r.last_status_text)}` : ""}`],
    ["servo/tracker faults", r.faults.length ? r.faults.map(esc).join("<br>") : "none", r.faults.length ? "bad" : "ok"],
    r.errors.length ? ["errors", r.errors.map(esc).join("<br>"), "bad"] : null,
    r.failsafe.length ? ["failsafes", r.failsafe.map(esc).join("<br>"), "warn"] : null,
  ]);
}

// -- the sweep -----------------------------------------------------------------------------
function drawSweep(s) {
  const w = s.sweep, g = w.grid;
  const over = w.poses !== null && w.next !== null && w.next >= w.poses;
  $("sweep-title").textContent = w.id === null ? "" : `#${w.id}${w.active ? ", running" : over ? ", done" : w.active === false ? ", stopped" : ""}`;
  let done = 0, skipped = 0, total = w.poses || 0;
  if (g) {
    for (const c of g.cells) { if (c === "d") done++; if (c === "s") skipped++; }
    total = g.cells.replace(/ /g, "").length;
  } else if (w.next !== null) {
    done = w.next - w.skipped.length; skipped = w.skipped.length;
  }
  const pct = total ? (100 * (done + skipped)) / total : 0;
  $("progress-bar").style.width = `${pct}%`;
  $("progress-text").textContent = total ? `sweep ${w.id ?? "?"}: ${done + skipped} of ${total} poses` +
    (skipped ? ` (${skipped} ${w.missing ? "missing" : "skipped"})` : "") : "no sweep";
  drawMissing(w);
  if (!g) return;
  const key = JSON.stringify([g.elevations, g.azimuths]);
  const box = $("grid");
  if (box.dataset.key !== key) {
    const head = `<tr><th>el \\ az</th>${g.azimuths.map((a) => `<th>${a}°</th>`).join("")}</tr>`;
    box.innerHTML = `<table>${head}${g.elevations.map((e, r) => `<tr><th>${e}°</th>${g.azimuths.map((a, c) =>
      `<td class=cell data-rc="${r},${c}" data-pose="${e}|${a}"></td>`).join("")}</tr>`).join("")}</table>`;
    box.dataset.key = key;
  }
  const mark = {d: "✓", s: "✗", m: "●", p: ""}, word = {d: "done", s: "skipped", m: "being measured", p: "pending"};
  box.querySelectorAll("td.cell").forEach((td) => {
    const [r, c] = td.dataset.rc.split(",").map(Number), st = g.cells[r * g.azimuths.length + c];
    const [e, a] = td.dataset.pose.split("|");
    td.className = `cell ${st}` + (td.dataset.pose === selectedPose() ? " sel" : "");
    td.textContent = mark[st] ?? "";
    td.title = `${e}° / ${a}°: ${word[st] ?? st}` + (st === "s" ? `: ${g.reasons[`${r},${c}`] ?? ""}` : "");
  });
}

// The poses an ended sweep could not measure, each with why (after its tries).
function drawMissing(w) {
  const m = w.missing || [], more = w.missing_left_out || 0, box = $("missing");
  box.hidden = !(m.length || more);
  box.innerHTML = box.hidden ? "" : `<h3>Missing: ${m.length + more} pose${m.length + more === 1 ? "" : "s"} not measured</h3><ul>` +
    m.map((k) => `<li>${deg(k.elevation)} / ${deg(k.azimuth)}${k.tries > 1 ? ` (${k.tries} tries)` : ""}: ${esc(k.reason)}</li>`).join("") +
    (more ? `<li>… and ${more} more</li>` : "") + "</ul>";
}

// -- captures ------------------------------------------------------------------------------
function selectedPose() {
  const c = state.cards.get(state.selected);
  return c && c.commanded ? `${Number(c.commanded[0])}|${Number(c.commanded[1])}` : null;
}

function cardHtml(c) {
  const src = `capture/${c.id}/thumb.png?r=${state.rev}`;
  return `<img loading=lazy ${state.thumbsHeld ? "data-src" : "src"}="${src}" alt="capture ${c.seq}">` +
    `${deg(c.elevation)} / ${azDeg(c.azimuth)}<br>seq ${c.seq}` + (c.space_auto ? ` · ${esc(c.space)} auto` : "");
}

// The browser asks a station for few pictures at a time: the chosen capture's go first, the
// cards' once those have loaded (or THUMBS_HELD_MS passed).
function releaseThumbs() {
  if (!state.thumbsHeld) return;
  state.thumbsHeld = false;
  document.querySelectorAll("#cards img[data-src]").forEach((img) => { img.src = img.dataset.src; img.removeAttribute("data-src"); });
  afterPictures($("cards"), () => once("btf-card-pictures"));
}
function once(mark) {  // the first time something was on the page, for the benchmarks
  if (!performance.getEntriesByName(mark).length) performance.mark(mark);
}
function afterPictures(box, then, which = "img") {
  const waits = [...box.querySelectorAll(which)].filter((i) => !i.complete)
    .map((i) => new Promise((done) => { i.addEventListener("load", done); i.addEventListener("error", done); }));
  Promise.all(waits).then(then);
}

function drawCards(list, fresh) {
  const box = $("cards");
  for (const c of list) {
    const old = state.cards.get(c.key);
    state.cards.set(c.key, c);
    let el = box.querySelector(`[data-key="${CSS.escape(c.key)}"]`);
    if (!el) {
      el = document.createElement("div");
      el.dataset.key = c.key;
      el.onclick = () => select(c.key, false);
      box.append(el);
    }
    el.className = "card" + (c.unlocked ? " unlocked" : "") + (fresh ? " new" : "") + (c.key === state.selected ? " sel" : "");
    el.dataset.seq = c.seq;
    el.dataset.id = c.id;
    el.title = `${c.scene || "robot " + c.robot} seq ${c.seq} at ${clock(c.time)}${c.camera ? "\n" + c.camera : ""}` +
      (c.space_auto ? `\nfeature space ${c.space} chosen automatically: ${c.space_auto}` : "");
    if (!old || old.id !== c.id) el.innerHTML = cardHtml(c);
    const seen = `${c.robot}:${c.seq}`;
    if (!(seen in window.btfPage.shown)) window.btfPage.shown[seen] = Date.now();
    if (!state.newest || c.id > state.newest.id) state.newest = c;
  }
  const sorted = [...box.children].sort((a, b) => {
    const x = state.cards.get(a.dataset.key), y = state.cards.get(b.dataset.key);
    return y.elevation - x.elevation || x.azimuth - y.azimuth;
  });
  if (sorted.some((el, i) => el !== box.children[i])) box.append(...sorted);
  $("captures-count").textContent = `latest of ${state.cards.size} pose${state.cards.size === 1 ? "" : "s"}`;
  if (state.follow && state.newest && state.newest.key !== state.selected) select(state.newest.key, true);
  else if (state.follow && state.newest && fresh && list.some((c) => c.key === state.selected)) select(state.selected, true);
}

async function select(key, following) {
  state.follow = following;
  $("follow").className = following ? "" : "off";
  $("follow").textContent = following ? "following newest" : "follow newest";
  state.selected = key;
  document.querySelectorAll("#cards .card").forEach((el) => el.classList.toggle("sel", el.dataset.key === key));
  if (state.snap) drawSweep(state.snap);
  const c = state.cards.get(key);
  if (!c) return;
  const want = `${c.id}:${state.rev}`;
  if (!($("detail").dataset.want || "").startsWith(`${c.id}:`)) {  // another capture: say so until it is drawn
    $("detail").innerHTML = `<p class=note>${esc(c.scene || "robot " + c.robot)} seq ${c.seq}: drawing…</p>`;
  }
  $("detail").dataset.want = want;
  if (state.asked) state.asked.abort();  // the capture chosen before: the station need not draw it now
  const asked = state.asked = new AbortController();
  try {
    const resp = await fetch(`capture/${c.id}/section?r=${state.rev}`, {signal: asked.signal});
    const text = await resp.text();
    if ($("detail").dataset.want !== want) return;  // another capture was chosen meanwhile
    $("detail").innerHTML = resp.ok ? text : `<p class=note>capture ${c.seq}: ${esc(text)}</p>`;
  } catch (e) {
    if (e.name === "AbortError") return;  // another capture was chosen
    $("detail").innerHTML = `<p class=bad>capture ${c.seq}: ${esc(e)}</p>`;
  }
  if ($("detail").querySelector("img.view")) afterPictures($("detail"), () => once("btf-selected-views"), "img.view");
  afterPictures($("detail"), () => {
    if ($("detail").querySelector("img")) once("btf-selected-pictures");
    releaseThumbs();
  });
}

$("grid").addEventListener("click", (ev) => {
  const td = ev.target.closest("td.cell");
  if (!td) return;
  const [e, a] = td.dataset.pose.split("|").map(Number);
  for (const c of state.cards.values()) {
    if (c.commanded && Math.abs(c.commanded[0] - e) < 0.05 && Math.abs(((c.commanded[1] - a + 540) % 360) - 180) < 0.05) {
      select(c.key, false);
      return;
    }
  }
});
$("follow").onclick = () => { if (state.newest) select(state.newest.key, true); };

// -- the BTF -------------------------------------------------------------------------------
// One region and band of one sweep against its main angle: the measured points, the curve the
// interpolation draws between them and leave one out, fetched again after every stored capture.
const btf = {source: "", region: "", stat: "mean", busy: false, again: false, data: null};
const SERIES = ["#0969da", "#cf222e", "#1a7f37", "#8250df", "#bf8700", "#57606a"];
const STAT_AXIS = {mean: "mean (level)", sd: "standard deviation (levels)", skewness: "skewness (no unit)",
  kurtosis: "kurtosis β2 (no unit)"};
const num = (v) => (Math.abs(v) >= 100 ? v.toFixed(0) : Math.abs(v) >= 10 ? v.toFixed(1) : v.toFixed(2));

async function fetchBtf() {
  if (btf.busy) { btf.again = true; return; }  // one request at a time; the latest state after it
  btf.busy = true;
  const q = new URLSearchParams();
  if (btf.source) {
    const [robot, scene, space] = JSON.parse(btf.source);
    q.set("robot", robot); q.set("scene", scene); q.set("space", space);
  }
  if (btf.region) { const [label, band] = btf.region.split(","); q.set("label", label); q.set("band", band); }
  try {
    const resp = await fetch(`api/btf?${q}`);
    const body = await resp.json();
    if (resp.ok) { btf.data = body; drawBtf(); } else $("btf-loo").innerHTML = `<p class=bad>BTF: ${esc(body.error || resp.status)}</p>`;
  } catch (e) {
    $("btf-loo").innerHTML = `<p class=bad>BTF: ${esc(e)}</p>`;
  } finally {
    btf.busy = false;
    if (btf.again) { btf.again = false; fetchBtf(); }
  }
}

function options(select, html, value) {
  if (select.dataset.opts !== html) { select.innerHTML = html; select.dataset.opts = html; }
  select.value = value;
}

function drawBtf() {
  const d = btf.data;
  options($("btf-source"), `<option value="">newest capture's</option>` + (d.sources || []).map((s) =>
    `<option value="${esc(JSON.stringify([s.robot, s.scene, s.space]))}">${esc(s.scene || "no scene")} · robot ${esc(s.robot)} · ${esc(s.space)}</option>`).join(""), btf.source);
  if (d.empty) {
    $("btf-plot").innerHTML = "";
    $("btf-title").textContent = "";
    $("btf-loo").innerHTML = `<p class=note>${esc(d.empty)}</p>`;
    return;
  }
  options($("btf-region"), d.regions.map(([l, b]) => `<option value="${l},${b}">region ${l}, band ${esc(d.bands[b] ?? b)}</option>`).join(""),
    `${d.label},${d.band}`);
  $("btf-title").textContent = `${d.scene || "robot " + d.robot}, region ${d.label}, band ${d.band_name}: ${d.points} point${d.points === 1 ? "" : "s"}`;
  plotBtf(d);
  looBtf(d);
}

function ticks(lo, hi, n) {
  const span = hi - lo, mag = 10 ** Math.floor(Math.log10(span / n));
  const step = [1, 2, 2.5, 5, 10].map((f) => f * mag).find((s) => span / s <= n) || span;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * span; v += step) out.push(v);
  return out;
}

function plotBtf(d) {
  const W = 600, H = 230, L = 58, R = 12, T = 10, B = 38, stat = btf.stat;
  const has = (p) => p[stat] !== null && p[stat] !== undefined;
  const pts = d.series.flatMap((s) => s.points), all = [...pts, ...d.series.flatMap((s) => s.curve)].filter(has);
  if (!all.length) { $("btf-plot").innerHTML = `<text x=${W / 2} y=${H / 2} text-anchor=middle>no ${stat} to draw</text>`; return; }
  let [x0, x1] = [Math.min(...pts.map((p) => p.angle)), Math.max(...pts.map((p) => p.angle))];
  let [y0, y1] = [Math.min(...all.map((p) => p[stat])), Math.max(...all.map((p) => p[stat]))];
  const px = Math.max((x1 - x0) * 0.03, 1), py = Math.max((y1 - y0) * 0.08, Math.abs(y1) * 0.02, 1e-3);
  [x0, x1, y0, y1] = [x0 - px, x1 + px, y0 - py, y1 + py];
  const sx = (v) => (L + ((v - x0) / (x1 - x0)) * (W - L - R)).toFixed(1);
  const sy = (v) => (H - B - ((v - y0) / (y1 - y0)) * (H - T - B)).toFixed(1);
  const out = ticks(y0, y1, 5).map((t) => `<line class=gridline x1=${L} x2=${W - R} y1=${sy(t)} y2=${sy(t)}></line>` +
    `<text x=${L - 4} y=${+sy(t) + 4} text-anchor=end>${num(t)}</text>`);
  out.push(...ticks(x0, x1, 8).map((t) => `<line class=axis x1=${sx(t)} x2=${sx(t)} y1=${H - B} y2=${H - B + 4}></line>` +
    `<text x=${sx(t)} y=${H - B + 16} text-anchor=middle>${num(t)}°</text>`));
  out.push(`<line class=axis x1=${L} x2=${W - R} y1=${H - B} y2=${H - B}></line><line class=axis x1=${L} x2=${L} y1=${T} y2=${H - B}></line>`,
    `<text x=${(L + W - R) / 2} y=${H - 4} text-anchor=middle>${esc(d.axis_title)} (°)</text>`,
    `<text transform="translate(13 ${(T + H - B) / 2}) rotate(-90)" text-anchor=middle>${esc(STAT_AXIS[stat])}</text>`);
  d.series.forEach((s, k) => {
    const c = SERIES[k % SERIES.length], line = s.curve.filter(has).map((p) => `${sx(p.angle)},${sy(p[stat])}`).join(" ");
    if (line) out.push(`<polyline class=curve stroke="${c}" points="${line}"></polyline>`);
    out.push(...s.points.filter(has).map((p) => `<circle class=pt cx=${sx(p.angle)} cy=${sy(p[stat])} r=3.5 fill="${c}">` +
      `<title>${esc(p.angles)} (seq ${p.seq}): ${stat} ${num(p[stat])}, ${p.family}, ${p.pixels} pixels</title></circle>`));
    if (d.series.length > 1) out.push(`<text x=${W - R - 4} y=${T + 12 + 13 * k} text-anchor=end style="fill:${c}">${esc(s.name)}</text>`);
  });
  $("btf-plot").innerHTML = out.join("");
}

function looBtf(d) {
  const s = d.loo.summary;
  const key = "<p class=note>● measured, — interpolated as <code>synth --angle</code> does. Leave one out: exact L1 between " +
    "an angle's level probabilities and those predicted from the other angles, beside the nearest angle alone.</p>";
  if (!s.interior) { $("btf-loo").innerHTML = key + "<p class=note>No angle has measured neighbours on both sides yet.</p>"; return; }
  const rows = d.loo.rows.map((r) => `<tr><td class=l>${esc(r.angle)}</td><td class=${r.interpolation_better ? "ok" : "bad"}>` +
    `${r.interpolated_l1.toFixed(4)}</td><td>${r.nearest_l1.toFixed(4)}</td><td class=l>${esc(r.nearest_angle)}</td></tr>` +
    (r.why_not ? `<tr><td></td><td colspan=3 class="l note">${esc(r.why_not)}</td></tr>` : "")).join("");
  $("btf-loo").innerHTML = key + `<p class=${s.interpolation_better === s.interior ? "ok" : "warn"}>Interpolation beats the nearest ` +
    `angle at ${s.interpolation_better} of ${s.interior} (mean L1 ${s.interpolated_mean_l1.toFixed(4)} against ${s.nearest_mean_l1.toFixed(4)})</p>` +
    `<div class=loo-rows><table><tr><th class=l>left out</th><th>interpolated L1</th><th>nearest L1</th><th class=l>nearest</th></tr>${rows}</table></div>`;
}

$("btf-source").onchange = (e) => { btf.source = e.target.value; btf.region = ""; fetchBtf(); };
$("btf-region").onchange = (e) => { btf.region = e.target.value; fetchBtf(); };
$("btf-stat").onchange = (e) => { btf.stat = e.target.value; if (btf.data && !btf.data.empty) plotBtf(btf.data); };

// -- events --------------------------------------------------------------------------------
const LOG_KEPT = 80;
function logEvent(ev) {
  if (ev.shown === false) return;  // e.g. the station's own STATUS poll (tools/station/events.py)
  const li = document.createElement("li");
  li.className = ev.tone || "";
  li.innerHTML = `<span class=t>${clock(ev.time)}</span> ${esc(ev.kind)}: ${esc(ev.text)}`;
  $("log").prepend(li);
  while ($("log").children.length > LOG_KEPT) $("log").lastChild.remove();
  if (ev.kind === "answer") answered(ev.command_id, ev.answer);
}

function answerText(a) {
  if (a.ok) {
    const shown = (k, v) => (k === "time" && typeof v === "number" && v > 1e9 ? new Date(v * 1000).toISOString().slice(0, 19) + "Z"
      : typeof v === "number" ? +v.toFixed(3) : v);  // the robot's clock as a time, not epoch seconds
    const empty = (v) => v === "" || v === null || (typeof v === "object" && !Object.keys(v).length);  // "paused=" says nothing
    const said = Object.entries(a.extras || {}).filter(([, v]) => !empty(v)).map(([k, v]) => `${k}=${shown(k, v)}`).join(" ");
    return [`ACK${said ? ": " + said : ""}`, "ok"];
  }
  return [`NACK ${a.reason}: ${a.text}`, "bad"];
}

function answered(cid, answer) {
  const out = state.waiting.get(cid);
  if (!out) { state.answers.set(cid, answer); return; }
  state.waiting.delete(cid);
  const [text, cls] = answerText(answer);
  out.textContent = text;
  out.className = `answer ${cls}`;
}

// -- commands ------------------------------------------------------------------------------
function drawAuth() {
  const can = state.authorized || state.token;
  $("token-box").hidden = !!can;
  document.querySelectorAll("form.command button").forEach((b) => { b.disabled = !can; });
}

document.querySelectorAll("form.command").forEach((form) => {
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const out = form.querySelector("output.answer");
    const fields = {};
    form.querySelectorAll("input[name]").forEach((i) => { fields[i.name] = i.value; });
    out.className = "answer note";
    out.textContent = "sending…";
    const headers = {"Content-Type": "application/json"};
    if (state.token) headers["X-BTF-Token"] = state.token;
    try {
      const resp = await fetch("api/command", {method: "POST", headers, body: JSON.stringify({name: form.dataset.command, fields})});
      const body = await resp.json();
      if (!resp.ok && resp.status !== 202) {
        out.className = "answer bad";
        out.textContent = body.error || `refused (${resp.status})`;
        return;
      }
      if (body.answer) { state.waiting.set(body.command_id, out); answered(body.command_id, body.answer); return; }
      state.waiting.set(body.command_id, out);
      out.textContent = `sent (command ${body.command_id}); waiting for the robot` +
        (state.snap && !state.snap.link.up ? ": the link is down, it goes when the robot is heard" : "…");
      if (state.answers.has(body.command_id)) answered(body.command_id, state.answers.get(body.command_id));
    } catch (e) {
      out.className = "answer bad";
      out.textContent = `not sent: ${e}`;
    }
  });
});
$("token-use").onclick = () => { state.token = $("token-input").value.trim(); drawAuth(); };

// -- the stream ----------------------------------------------------------------------------
function drawAll() {
  const s = state.snap;
  drawLink(s);
  drawRobot(s);
  drawSweep(s);
}

function connect() {
  const es = new EventSource("events");
  es.addEventListener("hello", (m) => {
    const h = JSON.parse(m.data);
    state.snap = h.snapshot; state.received = Date.now(); state.rev = h.rev; state.authorized = h.authorized;
    document.title = `btfscout: ${h.db}`;
    drawAll();
    drawCards(h.cards, false);
    if (!h.cards.length) releaseThumbs();
    setTimeout(releaseThumbs, THUMBS_HELD_MS);
    drawAuth();
    $("log").innerHTML = "";
    h.events.forEach(logEvent);
    $("conn").textContent = "live";
    $("conn").className = "note ok";
    if (!window.btfPage.hello) { window.btfPage.hello = Date.now(); once("btf-first-data"); }
    fetchBtf();
  });
  es.addEventListener("snapshot", (m) => { state.snap = JSON.parse(m.data).snapshot; state.received = Date.now(); drawAll(); });
  es.addEventListener("cards", (m) => { drawCards(JSON.parse(m.data).cards, true); fetchBtf(); });
  es.addEventListener("event", (m) => logEvent(JSON.parse(m.data).event));
  es.addEventListener("rev", (m) => {
    state.rev = JSON.parse(m.data).rev;
    // new drawings replace the old in place: the old picture stays until the new one has loaded
    document.querySelectorAll("#cards .card img").forEach((img) => {
      img.src = img.getAttribute("src").replace(/\?r=\d+$/, `?r=${state.rev}`);
    });
    if (state.selected) select(state.selected, state.follow);
  });
  es.onerror = () => { $("conn").textContent = "station unreachable: retrying"; $("conn").className = "note bad"; };
}

setInterval(() => {
  if (!state.snap) return;
  const t = heardText();
  $("heard").textContent = t;
  const cell = $("heard-cell");
  if (cell) cell.textContent = t;
}, 250);
connect();
