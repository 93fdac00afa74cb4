// Live view: one card per station, fed by the panel's WebSocket relay; operators also get the controls.
import { api, appendCertificateLinks, chart, coefficientRows, duration, el, num, session, showError, start, tickLabels, UNCERTAINTY_NOTE } from "/static/common.js";

const STALE_S = 2; // no telemetry for this long: the station is shown as silent
const NOT_SERVED_S = 5; // ... and for this long (or never heard): not served, with the command that serves it
const TRACE_MESSAGES = 20; // display traces kept: about 2 s of wall time (the engine sends 10 a second)
const SPEED_SPAN_S = 10; // wall seconds over which the station's speed is measured
const RATES_KEEP = 8;
const NOTICES_KEEP = 200;
const RENDER_MS = 100;
const FINAL = ["finished", "aborted", "estopped", "failed"];
const UNDER_WAY = ["running", "waiting_operator", "pausing", "paused"]; // the states with a time left
const IN_HISTORY = ["window", "trace", "point", "event", "fault"]; // topics the history holds

// Station seconds per wall second over the last few wall seconds of status messages (a simulated station runs
// faster than real time, and jumps through the waits it knows the end of).
class SpeedMeter {
  constructor() {
    this.samples = [];
    this.speed = null;
  }
  add(doc) {
    this.samples.push([doc.t_s, doc.wall_s]);
    while (doc.wall_s - this.samples[0][1] > SPEED_SPAN_S) this.samples.shift();
    const [t0, w0] = this.samples[0];
    if (doc.wall_s - w0 >= 1) this.speed = (doc.t_s - t0) / (doc.wall_s - w0);
  }
}

// Samples decimated to at most two per pixel column: the min and the max of each column's time bucket, in time
// order. A line through them is the true envelope of the motion (a stride would alias it into scattered dots).
export function minMaxPerPixel(t, z, columns) {
  const n = t.length;
  if (n <= 2 * columns) return [t, z];
  const t0 = t[0];
  const span = t[n - 1] - t0 || 1;
  const xs = [];
  const ys = [];
  let bucket = -1;
  let iMin = 0;
  let iMax = 0;
  const flush = () => {
    if (bucket < 0) return;
    const pair = iMin === iMax ? [iMin] : iMin < iMax ? [iMin, iMax] : [iMax, iMin];
    for (const i of pair) { xs.push(t[i]); ys.push(z[i]); }
  };
  for (let i = 0; i < n; i++) {
    const b = Math.min(columns - 1, Math.floor(((t[i] - t0) / span) * columns));
    if (b !== bucket) { flush(); bucket = b; iMin = i; iMax = i; }
    else { if (z[i] < z[iMin]) iMin = i; if (z[i] > z[iMax]) iMax = i; }
  }
  flush();
  return [xs, ys];
}

// The table's displacement over station time. Where the samples resolve the motion (spacing under a quarter
// period) the upper and lower envelope per pixel column (they coincide: the trace itself); where they do not (a
// simulated station at 100x sends a few samples per many periods) each sample as a dot, no line: a line through
// them would draw an alias of the motion. Gaps in the record are left open.
export function envelopeSeries(t, z, freqHz, columns) {
  const [xs, ys] = minMaxPerPixel(t, z, columns);
  const n = xs.length;
  const dts = [];
  for (let i = 1; i < n; i++) dts.push(xs[i] - xs[i - 1]);
  const median = dts.length ? [...dts].sort((a, b) => a - b)[Math.floor(dts.length / 2)] : 0;
  const resolved = !(freqHz > 0) || median < 0.25 / freqHz;
  const x = [];
  const line = [];
  const dots = [];
  for (let i = 0; i < n; i++) {
    if (resolved && i && median > 0 && xs[i] - xs[i - 1] > 5 * median) {
      x.push((xs[i] + xs[i - 1]) / 2); line.push(null); dots.push(null);
    }
    x.push(xs[i]); line.push(resolved ? ys[i] : null); dots.push(resolved ? null : ys[i]);
  }
  return { x, line, dots, resolved, spacing: median };
}

// The table's displacement from the grating as a continuous trace over station time (s): the last couple of
// wall seconds of display traces, min/max per pixel column.
class TracePlot {
  constructor(box) {
    this.box = box;
    this.messages = [];
    this.plot = null;
    this.updates = 0;
    this.title = el("p", { class: "plot-title" }, "Table displacement (grating): no motion yet");
    box.append(this.title);
  }
  add(data) {
    if (!data.t_s || !data.t_s.length) return;
    const last = this.messages.at(-1);
    if (last && data.t_s[0] < last.t_s[last.t_s.length - 1]) this.messages = []; // time went back: a new window
    this.messages.push(data);
    while (this.messages.length > TRACE_MESSAGES) this.messages.shift();
    this.dirty = true;
  }
  clear(why) {
    this.messages = [];
    this.title.textContent = `Table displacement (grating): ${why}`;
    if (this.plot) this.plot.setData([[], [], []]);
  }
  render() {
    if (!this.dirty) return;
    this.dirty = false;
    const t = [];
    const z = [];
    for (const m of this.messages) for (let i = 0; i < m.t_s.length; i++) { t.push(m.t_s[i]); z.push(m.z_m[i] * 1000); }
    if (!t.length) return;
    if (!this.plot) {
      this.plot = chart(this.box, {
        scales: { x: { time: false } },
        axes: [{ label: "station time (s)", values: tickLabels }, { label: "z (mm)", values: tickLabels }],
        series: [{ label: "station time (s)" },
          { label: "z (mm)", stroke: "#1565c0", width: 1, points: { show: false } },
          { label: "z at one instant (mm)", stroke: "#1565c0", paths: () => null, points: { show: true, size: 4, fill: "#1565c0" } }],
        legend: { show: false },
      }, [[], [], []]);
    }
    const freq = this.messages.at(-1).freq_hz;
    const columns = Math.max(Math.round(this.plot.bbox.width / devicePixelRatio), 100);
    const e = envelopeSeries(t, z, freq, columns);
    this.plot.setData([e.x, e.line, e.dots]);
    const span = t[t.length - 1] - t[0];
    this.title.textContent = `Table displacement (grating): the last ${num(span, 3)} s of station time, ${t.length} ` +
      (e.resolved ? "samples (min and max of each pixel column)"
        : `samples ${num(e.spacing, 3)} s apart, ${num(e.spacing * freq, 3)} periods of its ${num(freq, 3)} Hz: too ` +
          "sparse at this speed to draw the motion; each dot is where the table was, their spread its amplitude");
    this.box.dataset.zSpreadMm = (Math.max(...z) - Math.min(...z)).toFixed(3);
    this.updates += 1;
    this.box.dataset.updates = String(this.updates);
    this.box.dataset.points = String(e.x.length);
    this.box.dataset.spanS = span.toFixed(3);
    this.box.dataset.resolved = String(e.resolved);
    this.box.dataset.xAxis = "station time (s)";
  }
}

// The open window: pulses over the window's station time. The counter reports its count at the close (the
// preset); until then the count is the estimate preset x elapsed / expected, drawn as such, and the close as
// the measured point (Tm, preset) with its mean rate.
class WindowPlot {
  constructor(box) {
    this.box = box;
    this.docs = [];
    this.plot = null;
    this.caption = el("p", { class: "plot-title" }, "Open window: none yet");
    box.append(this.caption);
  }
  add(d) {
    if (d.event === "open" || (this.docs.length && this.docs[0].key !== d.key)) this.docs = [];
    this.docs.push(d);
    this.dirty = true;
  }
  clear() { this.docs = []; this.dirty = true; }
  render() {
    if (!this.dirty) return;
    this.dirty = false;
    const docs = this.docs.filter((d) => Number.isFinite(d.elapsed_s));
    if (!docs.length) { if (this.plot) this.plot.setData([[], [], [], []]); return; }
    const w = docs.at(-1);
    const closed = w.event === "close";
    const x = [];
    const est = [];
    const expected = [];
    const measured = [];
    const push = (xi, e, ex, m) => { x.push(xi); est.push(e); expected.push(ex); measured.push(m); };
    push(0, 0, 0, null);
    for (const d of docs) if (d.elapsed_s > 0 && d.event !== "close") push(d.elapsed_s, d.pulses_est, null, null);
    if (Number.isFinite(w.expected_s)) push(w.expected_s, null, w.preset_pulses, null);
    if (closed) push(w.elapsed_s, null, null, w.preset_pulses);
    const order = x.map((_, i) => i).sort((a, b) => x[a] - x[b]);
    const pick = (arr) => order.map((i) => arr[i]);
    if (!this.plot) {
      this.box.append(el("p", { class: "plot-legend" }, el("span", { class: "key est" }, "- - estimated (preset × elapsed / expected)"),
        el("span", { class: "key exp" }, "○ expected close"), el("span", { class: "key meas" }, "● counted at the close")));
      this.plot = chart(this.box, {
        legend: { show: false },
        scales: { x: { time: false } },
        axes: [{ label: "station time since the window opened (s)" }, { label: "pulses", size: 60 }],
        series: [{ label: "t (s)" },
          { label: "estimated (elapsed / expected x preset)", stroke: "#90a4ae", dash: [6, 4], spanGaps: true, points: { show: true, size: 4 } },
          { label: "expected close", stroke: "#1565c0", points: { show: true, size: 7 }, spanGaps: true },
          { label: "counted at the close", stroke: "#c62828", points: { show: true, size: 9, fill: "#c62828" }, paths: () => null }],
      }, [[], [], [], []]);
    }
    this.plot.setData([pick(x), pick(est), pick(expected), pick(measured)]);
    const rate = closed && w.rate_radps !== undefined ? `; mean rate ${num(w.rate_radps, 7)} rad/s` : "";
    this.caption.textContent = `Open window ${w.key}: ${closed ? `closed on its preset ${w.preset_pulses} pulses after ` +
      `${num(w.elapsed_s, 6)} s${rate}` : `${duration(w.elapsed_s)} of about ${duration(w.expected_s)}; ` +
      `about ${w.pulses_est} of ${w.preset_pulses} pulses (the counter reports at the close)`}`;
    this.box.dataset.event = w.event;
  }
}

// Each closed window's mean precession rate over the session.
class RatesPlot {
  constructor(box) {
    this.box = box;
    this.rates = []; // [key, rate_radps, elapsed_s]
    this.plot = null;
  }
  add(d) {
    if (d.rate_radps === undefined || this.rates.some((r) => r[0] === d.key && r[2] === d.elapsed_s)) return;
    this.rates.push([d.key, d.rate_radps, d.elapsed_s]);
    this.dirty = true;
  }
  clear() { this.rates = []; this.dirty = true; }
  render() {
    if (!this.dirty) return;
    this.dirty = false;
    if (!this.plot && this.rates.length) {
      this.plot = chart(this.box, {
        title: "Mean rate of each closed window",
        scales: { x: { time: false } },
        axes: [{ label: "window", incrs: [1, 2, 5, 10, 20, 50, 100, 200, 500] },
          { label: "rate (rad/s)", size: 90, values: tickLabels }],
        series: [{ label: "window" }, { label: "rate (rad/s)", stroke: "#2e7d32", paths: () => null, points: { show: true, size: 6, fill: "#2e7d32" } }],
        legend: { show: false },
      }, [[], []]);
    }
    if (this.plot) this.plot.setData([this.rates.map((_, i) => i + 1), this.rates.map((r) => r[1])]);
    this.box.dataset.points = String(this.rates.length);
  }
}

// The run's state as the operator needs it: a finished run whose analysis is still under way is 'analysing'.
function runState(p) {
  if (!p || !p.state) return "—";
  return p.state === "finished" && p.analysing ? "analysing" : p.state;
}

function stamp(doc) {
  const utc = Number.isFinite(doc.wall_s) ? new Date(doc.wall_s * 1000).toISOString().slice(11, 19) + " UTC" : "";
  const st = Number.isFinite(doc.t_s) ? `t = ${num(doc.t_s, 7)} s` : "";
  return [st, utc].filter(Boolean).join(" · ");
}

class StationView {
  constructor(info) {
    this.name = info.name;
    this.serveCommand = info.serve_command || `station serve --name ${info.name}`;
    this.speed = new SpeedMeter();
    this.last = {}; // latest data by topic
    this.seenFaults = new Set();
    this.sessionUid = null;
    this.silentS = info.relay ? info.relay.silent_s : null;
    this.heardReport = false;
    this.points = 0;
    this.skipUpTo = null; // seq of the newest message of the history just received (its frame only)
    this.dirty = true;
    this.build(info);
  }

  build(info) {
    const f = (cls) => el("span", { class: cls }, "—");
    this.f = {
      link: f("link"), state: f("state"), procedure: f("procedure"), key: f("key"), counts: f("counts"),
      eta: f("eta"), freq: f("freq"), head: f("head"), drive: f("drive"), rate: f("rate"), session: f("session"),
      points: f("points"),
    };
    this.bar = el("div", { class: "bar-fill" });
    this.progress = el("div", { class: "bar", role: "progressbar", "aria-label": "session progress",
      "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0" }, this.bar);
    this.notServed = el("div", { class: "not-served", role: "alert", hidden: true });
    this.pauseBox = el("div", { class: "pause-box", role: "status", hidden: true });
    this.results = el("section", { class: "results", hidden: true });
    this.traceBox = el("div", { class: "trace", dataset: { updates: "0" } });
    this.trace = new TracePlot(this.traceBox);
    this.windowBox = el("div", { class: "window-plot" });
    this.window = new WindowPlot(this.windowBox);
    this.ratesBox = el("div", { class: "rates-plot", dataset: { points: "0" } });
    this.ratesPlot = new RatesPlot(this.ratesBox);
    this.rateList = el("tbody");
    this.noticeList = el("ul", { class: "notices" });
    this.faultList = el("ul", { class: "faults" });
    const row = (label, field) => el("tr", {}, el("th", {}, label), el("td", {}, field));
    this.controls = el("section", { class: "controls", hidden: true });
    this.card = el("article", { class: "station", dataset: { station: info.name } },
      el("header", {}, el("h2", {}, info.title), this.f.link, el("span", { class: "badge" }, this.f.state)),
      this.notServed, this.pauseBox, this.results,
      el("div", { class: "grid" },
        el("section", {},
          el("h3", {}, "Session"),
          el("table", { class: "facts" }, row("procedure", this.f.procedure), row("session", this.f.session),
            row("point", this.f.key), row("measurements", this.f.counts), row("points stored", this.f.points)),
          this.progress, el("p", { class: "eta" }, this.f.eta),
          el("h3", {}, "Open window"), this.windowBox,
          el("p", {}, "mean rate at the last close: ", this.f.rate),
          el("div", { class: "scroll" }, el("table", { class: "rates" }, el("thead", {}, el("tr", {}, el("th", {}, "window"),
            el("th", {}, "rate (rad/s)"), el("th", {}, "length (s)"))), this.rateList)),
          this.ratesBox),
        el("section", {},
          el("h3", {}, "Table and head"),
          el("table", { class: "facts" }, row("table frequency", this.f.freq), row("indexing head", this.f.head),
            row("drive", this.f.drive)),
          this.traceBox),
        el("section", {},
          el("h3", {}, "Faults"), this.faultList,
          el("h3", {}, "Events (station time · UTC)"), this.noticeList)),
      this.controls);
  }

  handle(doc) {
    const d = doc.data;
    // The latest messages replayed after the history may be in it already: each message counts once.
    if (this.skipUpTo !== null && IN_HISTORY.includes(doc.topic) && doc.seq <= this.skipUpTo) return;
    if (doc.topic !== "history" && d && d.session_uid && d.session_uid !== this.sessionUid) this.newSession(d.session_uid);
    switch (doc.topic) {
      case "history":
        this.history(d);
        break;
      case "status":
        this.speed.add(doc);
        this.last.progress = { ...this.last.progress, ...d };
        break;
      case "progress":
        this.last.progress = { ...this.last.progress, ...d };
        break;
      case "state":
        this.last.progress = { ...this.last.progress, state: d.state, session_uid: d.session_uid };
        this.notice(doc, "state", d.state, FINAL.includes(d.state) && d.state !== "finished" ? "warning" : "info");
        break;
      case "window":
        this.window.add(d);
        if (d.event === "close") this.ratesPlot.add(d);
        break;
      case "motion":
        this.last.motion = d;
        if (!d.freq_hz) this.trace.clear("the table is at rest");
        break;
      case "trace":
        this.trace.add(d);
        break;
      case "point":
        this.points += 1;
        break;
      case "analysis":
        this.last.analysis = d;
        this.notice(doc, "analysis", d.summary.split("\n")[0], "info");
        this.showResults(d);
        break;
      case "event":
        this.notice(doc, d.kind, d.message, d.level);
        break;
      case "fault":
        this.notice(doc, d.kind, d.message, "error", true);
        break;
      default:
        return;
    }
    this.dirty = true;
  }

  // The session so far, sent by the panel when this browser connects: points, closes, events, window, traces.
  history(h) {
    const docs = [...h.points, ...h.closes, ...h.notices, ...h.window, ...h.traces];
    this.skipUpTo = docs.length ? Math.max(...docs.map((x) => x.seq)) : null;
    this.noticeList.replaceChildren();
    this.faultList.replaceChildren();
    this.seenFaults = new Set();
    if (h.session_uid && h.session_uid !== this.sessionUid) this.newSession(h.session_uid);
    this.points = h.points.length;
    for (const c of h.closes) this.ratesPlot.add(c.data);
    for (const w of h.window) this.window.add(w.data);
    for (const t of h.traces) this.trace.add(t.data);
    for (const n of h.notices) {
      if (n.topic === "fault") this.notice(n, n.data.kind, n.data.message, "error", true);
      else this.notice(n, n.data.kind, n.data.message, n.data.level);
    }
  }

  // A new run: what belonged to the last one goes.
  newSession(uid) {
    this.sessionUid = uid;
    this.points = 0;
    this.window.clear();
    this.ratesPlot.clear();
    this.trace.clear("no motion in this session yet");
    this.noticeList.replaceChildren();
    this.faultList.replaceChildren();
    this.seenFaults = new Set();
    this.results.hidden = true;
    this.results.replaceChildren();
    this.last.progress = {};
    delete this.last.analysis;
  }

  notice(doc, kind, message, level, fault = false) {
    const item = el("li", { class: level }, el("time", {}, stamp(doc)), " ", el("b", {}, kind), " ", message);
    (fault ? this.faultList : this.noticeList).prepend(item);
    for (const list of [this.faultList, this.noticeList]) {
      while (list.children.length > NOTICES_KEEP) list.lastChild.remove();
    }
  }

  // The coefficients with their units and uncertainties, and links to the report (and certificate), once the
  // session's analysis is in.
  showResults(a) {
    const uid = a.session_uid;
    const base = `/api/sessions/${encodeURIComponent(uid)}`;
    const rows = coefficientRows(a.results);
    const byResult = new Map();
    for (const r of rows) byResult.set(r.result, [...(byResult.get(r.result) || []), r]);
    const tables = [...byResult].map(([name, rs]) => {
      const doc = a.results[name] || {};
      const fit = Number.isFinite(doc.mu) && Number.isFinite(doc.mu_c)
        ? el("p", { class: doc.reliable === false || doc.mu >= doc.mu_c ? "bad" : "ok" },
          `μ = ${num(doc.mu, 3)} ${doc.mu < doc.mu_c ? "<" : "≥"} μc = ${num(doc.mu_c, 3)}: ` +
          (doc.mu < doc.mu_c ? "no outlier (seed 000 eq. 28)" : "a possible outlier (seed 000 eq. 28)") +
          (Number.isFinite(doc.sigma_residual) ? `; residual σ = ${num(doc.sigma_residual, 4)} rad/s` : ""))
        : null;
      return el("div", { class: "scroll" }, el("h4", {}, name),
        el("table", { class: "coefficients" },
          el("thead", {}, el("tr", {}, ["coefficient (unit)", "value", "u (k = 1)", "k", "U = k u"].map((h) => el("th", {}, h)))),
          el("tbody", {}, rs.map((r) => el("tr", { dataset: { coefficient: r.name } },
            el("td", {}, el("b", {}, r.name), " ", el("small", {}, r.unit ? `(${r.unit})` : "(unit not stated)")),
            ...(r.value === null ? [el("td", { colspan: "4", class: "note" }, `not identified${r.note ? `: ${r.note}` : ""}`)]
              : [el("td", {}, num(r.value, 7)), el("td", {}, r.u === null ? "—" : num(r.u, 3)), el("td", {}, num(r.k, 3)),
                el("td", {}, r.expanded === null ? "—" : num(r.expanded, 3))]))))),
        fit);
    });
    const links = el("p", { class: "links" },
      el("a", { href: `${base}/report`, target: "_blank", class: "report-link" }, "HTML report"),
      el("a", { href: `/sessions/${encodeURIComponent(uid)}` }, "session page"));
    appendCertificateLinks(links, uid);
    this.results.replaceChildren(el("h3", {}, `Results of session ${uid}`),
      ...(tables.length ? tables : [el("pre", {}, a.summary)]),
      el("p", {}, el("small", {}, UNCERTAINTY_NOTE)), links);
    this.results.hidden = false;
  }

  render() {
    const p = this.last.progress; // status (5/s beacon), progress (every step) and state, merged
    const state = runState(p);
    this.f.state.textContent = state;
    this.card.dataset.state = state;
    if (p) {
      const pct = Math.round(1000 * (p.fraction || 0)) / 10;
      this.bar.style.width = `${pct}%`;
      this.progress.setAttribute("aria-valuenow", String(pct));
      this.f.procedure.textContent = p.procedure || "—";
      this.f.key.textContent = p.key || "—";
      this.f.counts.textContent = `${p.done} of ${p.total}`;
      this.f.eta.textContent = this.etaText(state, p, pct);
      this.renderSessionLink(p.session_uid);
      this.f.head.textContent = p.index_deg === null || p.index_deg === undefined ? "—" : `${num(p.index_deg, 6)}°`;
      this.f.drive.textContent = p.busy === undefined ? "—" : this.driveText(state, p);
      for (const fault of p.faults || []) this.faultOnce(fault);
    }
    this.f.points.textContent = String(this.points);
    const m = this.last.motion;
    const fHz = this.tableHz();
    this.f.freq.textContent = fHz === null ? "—"
      : fHz === 0 ? "at rest" : `${num(fHz, 6)} Hz` + (m && m.commanded_hz !== m.freq_hz ? ` (commanded ${num(m.commanded_hz, 6)} Hz)` : "");
    const rates = this.ratesPlot.rates;
    this.f.rate.textContent = rates.length ? `${num(rates.at(-1)[1], 7)} rad/s (${rates.at(-1)[0]})` : "—";
    this.rateList.replaceChildren(...rates.slice(-RATES_KEEP).reverse().map(([k, r, t]) =>
      el("tr", {}, el("td", {}, k), el("td", {}, num(r, 7)), el("td", {}, num(t, 6)))));
    this.trace.render();
    this.window.render();
    this.ratesPlot.render();
    this.renderLink();
    this.renderPause(state, fHz);
    this.renderControls(state, p);
  }

  // The time left only while a run is under way; otherwise what the run came to.
  etaText(state, p, pct) {
    const done = `${pct.toFixed(1)} % (${p.done} of ${p.total} measurements)`;
    if (state === "analysing") return `${done}; measurements done, analysing the session: the results follow`;
    if (!UNDER_WAY.includes(state)) return state === "idle" || state === "—" ? "no run under way" : `${state}: ${done}`;
    const speed = this.speed.speed;
    const wall = speed && speed > 0 ? `, about ${duration(p.eta_s / speed)} at ${num(speed, 3)}x` : "";
    return `${done}; ETA ${duration(p.eta_s)} of station time${wall} (dry-run estimate ${duration(p.estimate_total_s)})`;
  }

  // The table's frequency, Hz: at rest once the engine says so (status: it sets 0 when the table has stopped,
  // after a ramp down or an abort's safe stop), else the drive's measured one (motion), else the commanded one.
  tableHz() {
    const m = this.last.motion;
    const p = this.last.progress;
    const commanded = p && p.freq_hz !== undefined && p.freq_hz !== null ? p.freq_hz : null;
    if (commanded === 0) return 0;
    if (m && m.freq_hz !== undefined) return m.freq_hz;
    return commanded;
  }

  renderLink() {
    const never = this.silentS === null || this.silentS === undefined;
    const silent = never || this.silentS > STALE_S;
    const notServed = this.heardReport && (never || this.silentS > NOT_SERVED_S);
    this.f.link.textContent = !this.heardReport ? "connecting" : never ? "not served"
      : notServed ? `not served: silent for ${duration(this.silentS)}` : silent ? `silent for ${duration(this.silentS)}` : "live";
    this.f.link.className = `link ${silent ? "bad" : "ok"}`;
    this.card.dataset.served = notServed ? "no" : "yes";
    this.card.dataset.heard = this.heardReport && never ? "never" : "yes";
    this.notServed.hidden = !notServed;
    if (notServed && !this.notServed.dataset.shown) {
      this.notServed.dataset.shown = "1";
      this.notServed.replaceChildren(
        el("p", {}, el("b", {}, "Station not served. "), never ? "The panel has heard nothing from this station since it started."
          : "The station has stopped publishing its telemetry.",
          " Start it on the station computer (or check the endpoints in the panel's configuration):"),
        el("pre", {}, el("code", {}, this.serveCommand)));
    }
    if (!notServed) delete this.notServed.dataset.shown;
  }

  // A paused run says whether the table is at rest or still vibrating, and offers to bring it to rest.
  renderPause(state, fHz) {
    const paused = state === "paused" || state === "pausing";
    this.pauseBox.hidden = !paused;
    if (!paused) { this.pauseBox.dataset.table = ""; return; }
    const vibrating = fHz !== null && fHz > 0;
    const table = vibrating ? "vibrating" : "at rest";
    if (this.pauseBox.dataset.table === table && this.pauseBox.dataset.state === state) return;
    this.pauseBox.dataset.table = table;
    this.pauseBox.dataset.state = state;
    const what = state === "pausing" ? "Pausing at the next safe point" : "Paused";
    const text = vibrating
      ? `${what}: the table is still vibrating at ${num(fHz, 4)} Hz (the run holds the crank at speed so that it resumes where it stopped).`
      : `${what}: the table is at rest.`;
    const parts = [el("p", {}, el("b", {}, text))];
    if (vibrating && session.role === "operator") {
      parts.push(el("p", {}, "To bring it to rest, abort the run: the engine ramps the table down and the session keeps " +
        "every point it measured (resume it later from its session page or with `station resume UID`). ",
      el("button", { type: "button", class: "warn", dataset: { action: "rest" }, onclick: () => this.bringToRest() },
        "Bring the table to rest (abort)")));
    } else if (vibrating) parts.push(el("p", {}, "An operator can bring it to rest by aborting the run."));
    this.pauseBox.replaceChildren(...parts);
  }

  async bringToRest() {
    if (!confirm(`Abort the paused run on ${this.name} and bring the table to rest? The session keeps what it measured.`)) return;
    try {
      await api(`/api/stations/${this.name}/abort`, { method: "POST" });
    } catch (err) {
      this.pauseBox.append(el("p", { class: "error", role: "alert" }, err.message));
    }
  }

  driveText(state, p) {
    if (state === "estopped") return "EMERGENCY STOP";
    if (p.drive_fault) return `fault: ${p.drive_fault}`;
    const drive = p.drive_state ? ` (${p.drive_state.toLowerCase()})` : "";
    if (!p.busy) return `idle${drive}`;
    return (p.freq_hz > 0 ? "vibrating" : "table at rest") + drive;
  }

  faultOnce(message) {
    if (this.seenFaults.has(message)) return;
    this.seenFaults.add(message);
    this.notice({}, "fault", message, "error", true);
  }

  renderSessionLink(uid) {
    if (!uid || this.f.session.dataset.uid === uid) return;
    this.f.session.dataset.uid = uid;
    this.f.session.replaceChildren(el("a", { href: `/sessions/${encodeURIComponent(uid)}` }, uid));
  }

  renderControls(state, p) {
    if (!this.buttons) return;
    const busy = p ? Boolean(p.busy) : false;
    const set = (name, on) => { this.buttons[name].disabled = !on; };
    set("start", !busy);
    set("plan", true);
    set("pause", state === "running");
    set("resume", state === "paused" || state === "pausing");
    set("abort", busy && !FINAL.includes(state) && state !== "analysing");
    set("reset", !busy && (state === "estopped" || state === "failed" || Boolean(p && (p.head_held || p.drive_fault))));
  }
}

// The start form: fields from the procedure's declared parameters, checked before anything is sent.
class StartForm {
  constructor(view, library) {
    this.view = view;
    this.library = library;
    this.fields = [];
    const here = library.filter((p) => !p.not_here);
    this.procedure = el("select", { name: "procedure", onchange: () => this.build() },
      here.map((p) => el("option", { value: p.name }, p.title)));
    this.elsewhere = elsewhere(library.filter((p) => p.not_here));
    this.serial = el("input", { name: "instrument_serial", value: "SIM-PIGA-0001", maxlength: "64",
      pattern: "[ -~]*" });
    this.params = el("div", { class: "params" });
    this.result = el("p", { class: "result", role: "status" });
    this.error = el("p", { class: "error", role: "alert", hidden: true });
    this.warnings = el("div", { class: "design-warnings", role: "alert" });
  }

  spec() {
    return this.library.find((p) => p.name === this.procedure.value);
  }

  build() {
    this.fields = this.spec().params.map((p) => this.field(p));
    this.params.replaceChildren(...this.fields.map((f) => f.label));
  }

  field(p) {
    let input;
    if (p.kind === "bool") input = el("input", { type: "checkbox", name: p.name, checked: Boolean(p.default) });
    else if (p.choices) {
      input = el("select", { name: p.name }, p.choices.map((c) => el("option", { value: c, selected: c === p.default }, c)));
    } else if (p.kind === "list") {
      input = el("input", { type: "text", name: p.name, value: (p.default || []).join(", "), inputmode: "decimal" });
    } else if (p.kind === "float" || p.kind === "int") {
      input = el("input", { type: "number", name: p.name, value: p.default ?? "", min: p.min ?? null, max: p.max ?? null,
        step: p.kind === "int" ? "1" : "any" });
    } else input = el("input", { type: "text", name: p.name, value: p.default ?? "" });
    const hint = el("small", {}, `${p.name} = ${p.allowed}${p.help ? ` — ${p.help}` : ""}`);
    const problem = el("small", { class: "error field-error", role: "alert" });
    input.addEventListener("input", () => this.read());
    const label = el("label", {}, el("span", {}, p.label), input, hint, problem);
    return { p, input, label, problem };
  }

  // {params} if every field is valid, else null with each defect shown next to its field.
  read() {
    const params = {};
    let ok = true;
    for (const { p, input, problem } of this.fields) {
      const [value, error] = parseParam(p, input);
      input.setCustomValidity(error || "");
      problem.textContent = error || "";
      if (error) ok = false;
      else if (value !== undefined) params[p.name] = value;
    }
    return ok ? params : null;
  }

  async send(kind, confirm = false) {
    this.error.hidden = true;
    this.warn([]);
    const params = this.read();
    if (params === null) {
      showError(this.error, "fix the marked parameters first");
      return;
    }
    const body = { procedure: this.procedure.value, params };
    if (kind === "start") Object.assign(body, { instrument_serial: this.serial.value, confirm });
    try {
      const r = await api(`/api/stations/${this.view.name}/${kind}`, { method: "POST", body });
      const plan = kind === "start" ? r.result.plan : r;
      const what = kind === "start" ? `started session ${r.result.session_uid}: ` : "dry run: ";
      this.result.textContent = `${what}${plan.n_measurements} measurements, ${duration(plan.total_s)} of station time`;
      if (kind !== "start") this.warn(plan.warnings);  // a start's warnings were confirmed before it (409 first)
    } catch (err) {
      if (err.status === 409 && err.detail?.warnings) this.warn(err.detail.warnings, true);
      else showError(this.error, err);
    }
  }

  // The design's warnings, each with its reason and fix; after a start held back by them, a button to confirm it.
  warn(warnings, confirmable = false) {
    const confirm = el("button", { type: "button", class: "warn", dataset: { action: "confirm" },
      onclick: () => this.send("start", true) }, "Confirm and start");
    this.warnings.replaceChildren(...(warnings.length ? [el("p", {}, el("b", {}, "The design has warnings:")),
      el("ul", {}, warnings.map((w) => el("li", {}, w.line)))] : []), ...(confirmable ? [confirm] : []));
  }
}

// The procedures this station cannot run, each with the shipped station files it runs on and why not here.
function elsewhere(procedures) {
  if (!procedures.length) return null;
  return el("details", { class: "elsewhere" },
    el("summary", {}, `${procedures.length} more procedures need another station`),
    el("ul", {}, procedures.map((p) => el("li", { dataset: { procedure: p.name } }, el("b", {}, p.title), ": ",
      p.station_files.length ? `runs on the station file ${p.station_files.join(" or ")} ` +
        `(station serve --station ${p.station_files[0].replace(/\.toml$/, "")})` : "no shipped station file runs it",
      el("br"), el("small", {}, `not here: ${p.not_here}`)))));
}

function parseParam(p, input) {
  const where = `${p.name} = `;
  if (p.kind === "bool") return [input.checked, null];
  if (p.choices || p.kind === "str") return [input.value, null];
  const raw = input.value.trim();
  if (raw === "") return p.required ? [undefined, `${where}(empty): required, ${p.allowed}`] : [undefined, null];
  const inRange = (x) => Number.isFinite(x) && (p.min === null || x >= p.min) && (p.max === null || x <= p.max);
  if (p.kind === "list") {
    const parts = raw.split(/[\s,;]+/).filter(Boolean);
    const values = parts.map(Number);
    const bad = parts.find((s, i) => !inRange(values[i]));
    if (bad !== undefined || !values.length) return [undefined, `${where}${bad ?? raw}: expected ${p.allowed}`];
    return [values, null];
  }
  const x = Number(raw);
  if (!inRange(x) || (p.kind === "int" && !Number.isInteger(x))) return [undefined, `${where}${raw}: expected ${p.allowed}`];
  return [x, null];
}

function buildControls(view, library) {
  const form = new StartForm(view, library);
  const act = (name) => async () => {
    form.error.hidden = true;
    if (name === "abort" && !confirm(`Abort the run on ${view.name}? The session keeps what it measured.`)) return;
    if (name === "reset" && !confirm(`Reset ${view.name}? Only once the cause of the stop or fault is removed.`)) return;
    try {
      await api(`/api/stations/${view.name}/${name}`, { method: "POST" });
      form.result.textContent = `${name}: sent`;
    } catch (err) {
      showError(form.error, err);
    }
  };
  const button = (name, text, cls, onclick) => el("button", { type: "button", class: cls, dataset: { action: name }, onclick }, text);
  view.buttons = {
    plan: button("plan", "Dry run", "", () => form.send("plan")),
    start: button("start", "Start", "primary", () => form.send("start")),
    pause: button("pause", "Pause", "", act("pause")),
    resume: button("resume", "Resume", "", act("resume")),
    abort: button("abort", "Abort", "warn", act("abort")),
    estop: button("estop", "EMERGENCY STOP", "estop", act("estop")),
    reset: button("reset", "Reset", "", act("reset")),
  };
  const b = view.buttons;
  view.controls.replaceChildren(
    el("h3", {}, "Control"),
    el("div", { class: "run-buttons" }, b.pause, b.resume, b.abort, b.estop, b.reset),
    el("form", { class: "start-form", onsubmit: (e) => e.preventDefault() },
      el("label", {}, el("span", {}, "procedure"), form.procedure), form.elsewhere,
      el("label", {}, el("span", {}, "instrument serial"), form.serial),
      form.params,
      el("div", {}, b.plan, b.start)),
    form.result, form.warnings, form.error);
  form.build();
  view.controls.hidden = false;
}

function connect(views, status) {
  const names = new Map(views.map((v) => [v.name, v]));
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/telemetry`);
  ws.onopen = () => {
    status.textContent = "panel connected";
    status.className = "ok";
  };
  ws.onmessage = (event) => {
    for (const doc of JSON.parse(event.data)) {
      if (doc.topic === "relay") {
        status.textContent = `panel connected; ${doc.data.dropped} messages dropped for this browser`;
        for (const [name, stats] of Object.entries(doc.data.feeds)) {
          const view = names.get(name);
          if (view) { view.silentS = stats.silent_s; view.heardReport = true; view.dirty = true; }
        }
      } else names.get(doc.station)?.handle(doc);
    }
    for (const v of views) v.skipUpTo = null; // the replay comes in the first frame; later ones are new
  };
  ws.onclose = (event) => {
    if (event.code === 4401) { location.assign("/login"); return; }
    status.textContent = "panel disconnected: reconnecting";
    status.className = "bad";
    setTimeout(() => connect(views, status), 1000);
  };
}

async function main() {
  await start("/");
  const stations = await api("/api/stations");
  const views = stations.map((s) => new StationView(s));
  document.querySelector("#stations").replaceChildren(...views.map((v) => v.card));
  if (session.role === "operator") {
    for (const view of views) {
      api(`/api/stations/${view.name}/library`).then((lib) => buildControls(view, lib))
        .catch((err) => { view.controls.hidden = false; view.controls.replaceChildren(el("p", { class: "error" }, err.message)); });
    }
  }
  connect(views, document.querySelector("#connection"));
  let lastRender = 0;
  const frame = (now) => {
    if (now - lastRender >= RENDER_MS) {
      lastRender = now;
      for (const v of views) if (v.dirty) { v.dirty = false; v.render(); }
    }
    requestAnimationFrame(frame);
  };
  requestAnimationFrame(frame);
}

main();
