// Live view: one card per station, fed by the panel's WebSocket relay; operators also get the controls.
import { api, chart, duration, el, num, session, showError, start } from "/static/common.js";

const STALE_S = 2; // no telemetry for this long: the station is shown as silent
const TRACE_POINTS = 600; // samples in the displacement plot (the grating display stream gives ~250 per wall second)
const SPEED_SPAN_S = 10; // wall seconds over which the station's speed is measured
const RATES_KEEP = 8;
const NOTICES_KEEP = 30;
const RENDER_MS = 100;
const FINAL = ["finished", "aborted", "estopped", "failed"];

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

// The table's displacement: against phase (t mod 1/f) when the station runs faster than real time, else time.
class TracePlot {
  constructor(box) {
    this.box = box;
    this.messages = [];
    this.mode = null;
    this.plot = null;
    this.updates = 0;
  }
  add(data, speed) {
    this.messages.push(data);
    let total = this.messages.reduce((n, m) => n + m.t_s.length, 0);
    while (this.messages.length > 1 && total - this.messages[0].t_s.length >= TRACE_POINTS) {
      total -= this.messages.shift().t_s.length;
    }
    const mode = speed !== null && speed > 2 && data.freq_hz > 0 ? "phase" : "time";
    if (mode !== this.mode) this.reset(mode);
    const pts = [];
    for (const m of this.messages) {
      const period = m.freq_hz > 0 ? 1 / m.freq_hz : 0;
      for (let i = 0; i < m.t_s.length; i++) {
        const x = mode === "phase" && period ? (360 * (m.t_s[i] % period)) / period : m.t_s[i];
        pts.push([x, m.z_m[i] * 1000]);
      }
    }
    pts.sort((a, b) => a[0] - b[0]);
    this.plot.setData([pts.map((p) => p[0]), pts.map((p) => p[1])]);
    this.updates += 1;
    this.box.dataset.updates = String(this.updates);
    this.box.dataset.points = String(pts.length);
  }
  reset(mode) {
    this.mode = mode;
    this.messages = this.messages.slice(-1);
    if (this.plot) this.plot.destroy();
    const x = mode === "phase" ? "phase in the table period (deg)" : "station time (s)";
    this.plot = chart(this.box, {
      title: "Table displacement (grating)",
      scales: { x: { time: false } },
      axes: [{ label: x }, { label: "z (mm)" }],
      series: [{ label: x }, { label: "z (mm)", stroke: "#1565c0", paths: () => null,
        points: { show: true, size: 3, fill: "#1565c0" } }],
      legend: { show: false },
    }, [[], []]);
  }
}

class StationView {
  constructor(info) {
    this.name = info.name;
    this.speed = new SpeedMeter();
    this.last = {}; // latest data by topic
    this.rates = [];
    this.seenFaults = new Set();
    this.sessionUid = null;
    this.silentS = null;
    this.dirty = true;
    this.build(info);
  }

  build(info) {
    const f = (cls) => el("span", { class: cls }, "—");
    this.f = {
      link: f("link"), state: f("state"), procedure: f("procedure"), key: f("key"), counts: f("counts"),
      eta: f("eta"), freq: f("freq"), head: f("head"), drive: f("drive"), window: f("window"),
      windowTime: f("window-time"), rate: f("rate"), session: f("session"),
    };
    this.bar = el("div", { class: "bar-fill" });
    this.progress = el("div", { class: "bar", role: "progressbar", "aria-label": "session progress",
      "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0" }, this.bar);
    this.windowBar = el("div", { class: "bar-fill" });
    this.windowProgress = el("div", { class: "bar small", role: "progressbar", "aria-label": "window pulses",
      "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0" }, this.windowBar);
    this.traceBox = el("div", { class: "trace", dataset: { updates: "0" } });
    this.trace = new TracePlot(this.traceBox);
    this.rateList = el("tbody");
    this.noticeList = el("ul", { class: "notices" });
    this.faultList = el("ul", { class: "faults" });
    const row = (label, field) => el("tr", {}, el("th", {}, label), el("td", {}, field));
    this.controls = el("section", { class: "controls", hidden: true });
    this.card = el("article", { class: "station", dataset: { station: info.name } },
      el("header", {}, el("h2", {}, info.title), this.f.link, el("span", { class: "badge" }, this.f.state)),
      el("div", { class: "grid" },
        el("section", {},
          el("h3", {}, "Session"),
          el("table", { class: "facts" }, row("procedure", this.f.procedure), row("session", this.f.session),
            row("point", this.f.key), row("measurements", this.f.counts)),
          this.progress, el("p", { class: "eta" }, this.f.eta),
          el("h3", {}, "Open window"),
          el("p", {}, this.f.window), this.windowProgress, el("p", {}, this.f.windowTime),
          el("p", {}, "precession rate at the last close: ", this.f.rate),
          el("table", { class: "rates" }, el("thead", {}, el("tr", {}, el("th", {}, "window"),
            el("th", {}, "rate (rad/s)"), el("th", {}, "length (s)"))), this.rateList)),
        el("section", {},
          el("h3", {}, "Table and head"),
          el("table", { class: "facts" }, row("table frequency", this.f.freq), row("indexing head", this.f.head),
            row("drive", this.f.drive)),
          this.traceBox),
        el("section", {},
          el("h3", {}, "Faults"), this.faultList,
          el("h3", {}, "Events"), this.noticeList)),
      this.controls);
  }

  handle(doc) {
    const d = doc.data;
    if (d.session_uid && d.session_uid !== this.sessionUid) this.newSession(d.session_uid);
    switch (doc.topic) {
      case "status":
        this.speed.add(doc);
        this.last.progress = { ...this.last.progress, ...d };
        break;
      case "progress":
        this.last.progress = { ...this.last.progress, ...d };
        break;
      case "state":
        this.last.progress = { ...this.last.progress, state: d.state, session_uid: d.session_uid };
        this.notice("state", d.state, FINAL.includes(d.state) && d.state !== "finished" ? "warning" : "info");
        break;
      case "window":
        this.last.window = d;
        if (d.event === "close" && d.rate_radps !== undefined) {
          this.rates.unshift([d.key, d.rate_radps, d.elapsed_s]);
          this.rates.length = Math.min(this.rates.length, RATES_KEEP);
        }
        break;
      case "motion":
        this.last.motion = d;
        break;
      case "trace":
        this.trace.add(d, this.speed.speed);
        break;
      case "analysis":
        this.last.analysis = d;
        this.notice("analysis", d.summary.split("\n")[0], "info");
        break;
      case "event":
        this.notice(d.kind, d.message, d.level);
        break;
      case "fault":
        this.notice(d.kind, d.message, "error", true);
        break;
      default:
        return;
    }
    this.dirty = true;
  }

  // A new run: what belonged to the last one goes.
  newSession(uid) {
    this.sessionUid = uid;
    this.rates = [];
    delete this.last.window;
  }

  // The relay replays recent events and faults to a browser that (re)connects.
  clearNotices() {
    this.noticeList.replaceChildren();
    this.faultList.replaceChildren();
    this.seenFaults = new Set();
  }

  notice(kind, message, level, fault = false) {
    const item = el("li", { class: level }, el("b", {}, kind), " ", message);
    (fault ? this.faultList : this.noticeList).prepend(item);
    for (const list of [this.faultList, this.noticeList]) {
      while (list.children.length > NOTICES_KEEP) list.lastChild.remove();
    }
  }

  render() {
    const p = this.last.progress; // status (5/s beacon), progress (every step) and state, merged
    const state = (p && p.state) || "—";
    this.f.state.textContent = state;
    this.card.dataset.state = state;
    if (p) {
      const pct = Math.round(1000 * (p.fraction || 0)) / 10;
      this.bar.style.width = `${pct}%`;
      this.progress.setAttribute("aria-valuenow", String(pct));
      this.f.procedure.textContent = p.procedure || "—";
      this.f.key.textContent = p.key || "—";
      this.f.counts.textContent = `${p.done} of ${p.total}`;
      const speed = this.speed.speed;
      const wall = speed && speed > 0 ? `, about ${duration(p.eta_s / speed)} at ${num(speed, 3)}x` : "";
      this.f.eta.textContent = `${pct.toFixed(1)} %; ETA ${duration(p.eta_s)} of station time${wall} ` +
        `(dry-run estimate ${duration(p.estimate_total_s)})`;
      this.renderSessionLink(p.session_uid);
      this.f.head.textContent = p.index_deg === null || p.index_deg === undefined ? "—" : `${num(p.index_deg, 6)}°`;
      this.f.drive.textContent = p.busy === undefined ? "—" : this.driveText(state, p);
      for (const fault of p.faults || []) this.faultOnce(fault);
    }
    const m = this.last.motion;
    const fHz = m ? m.freq_hz : p && p.freq_hz;
    this.f.freq.textContent = fHz === undefined || fHz === null ? "—"
      : fHz === 0 ? "at rest" : `${num(fHz, 6)} Hz` + (m && m.commanded_hz !== m.freq_hz ? ` (commanded ${num(m.commanded_hz, 6)} Hz)` : "");
    const w = this.last.window;
    if (w) {
      const pulses = w.event === "close" ? w.preset_pulses : w.pulses_est; // a window closes on its preset count
      const pct = w.preset_pulses ? Math.min(100, (100 * pulses) / w.preset_pulses) : 0;
      this.windowBar.style.width = `${pct}%`;
      this.windowProgress.setAttribute("aria-valuenow", pct.toFixed(1));
      this.f.window.textContent = `${w.key}: ${pulses} of ${w.preset_pulses} pulses (${w.event})`;
      this.f.windowTime.textContent = `${duration(w.elapsed_s)} of about ${duration(w.expected_s)}`;
    }
    this.f.rate.textContent = this.rates.length ? `${num(this.rates[0][1], 6)} rad/s (${this.rates[0][0]})` : "—";
    this.rateList.replaceChildren(...this.rates.map(([k, r, t]) =>
      el("tr", {}, el("td", {}, k), el("td", {}, num(r, 6)), el("td", {}, num(t, 5)))));
    const silent = this.silentS === null || this.silentS > STALE_S;
    this.f.link.textContent = this.silentS === null ? "no telemetry yet"
      : silent ? `silent for ${duration(this.silentS)}` : "live";
    this.f.link.className = `link ${silent ? "bad" : "ok"}`;
    this.renderControls(state, p);
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
    this.notice("fault", message, "error", true);
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
    set("abort", busy && !FINAL.includes(state));
    set("reset", !busy && (state === "estopped" || state === "failed" || Boolean(p && (p.head_held || p.drive_fault))));
  }
}

// The start form: fields from the procedure's declared parameters, checked before anything is sent.
class StartForm {
  constructor(view, library) {
    this.view = view;
    this.library = library;
    this.fields = [];
    this.procedure = el("select", { name: "procedure", onchange: () => this.build() },
      library.map((p) => el("option", { value: p.name }, `${p.title} (${p.name})`)));
    this.serial = el("input", { name: "instrument_serial", value: "SIM-PIGA-0001", maxlength: "64",
      pattern: "[ -~]*" });
    this.params = el("div", { class: "params" });
    this.result = el("p", { class: "result", role: "status" });
    this.error = el("p", { class: "error", role: "alert", hidden: true });
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
    const hint = el("small", {}, `${p.allowed}${p.help ? ` — ${p.help}` : ""}`);
    const problem = el("small", { class: "error field-error", role: "alert" });
    input.addEventListener("input", () => this.read());
    const label = el("label", {}, el("span", {}, p.name + (p.unit ? ` (${p.unit})` : "")), input, hint, problem);
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

  async send(kind) {
    this.error.hidden = true;
    const params = this.read();
    if (params === null) {
      showError(this.error, "fix the marked parameters first");
      return;
    }
    const body = { procedure: this.procedure.value, params };
    if (kind === "start") body.instrument_serial = this.serial.value;
    try {
      const r = await api(`/api/stations/${this.view.name}/${kind}`, { method: "POST", body });
      const plan = kind === "start" ? r.result.plan : r;
      const what = kind === "start" ? `started session ${r.result.session_uid}: ` : "dry run: ";
      this.result.textContent = `${what}${plan.n_measurements} measurements, ${duration(plan.total_s)} of station time`;
    } catch (err) {
      showError(this.error, err);
    }
  }
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
      el("label", {}, el("span", {}, "procedure"), form.procedure),
      el("label", {}, el("span", {}, "instrument serial"), form.serial),
      form.params,
      el("div", {}, b.plan, b.start)),
    form.result, form.error);
  form.build();
  view.controls.hidden = false;
}

function connect(views, status) {
  const names = new Map(views.map((v) => [v.name, v]));
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/telemetry`);
  ws.onopen = () => {
    status.textContent = "connected";
    status.className = "ok";
    for (const v of views) v.clearNotices();
  };
  ws.onmessage = (event) => {
    for (const doc of JSON.parse(event.data)) {
      if (doc.topic === "relay") {
        status.textContent = `connected; ${doc.data.dropped} messages dropped for this browser`;
        for (const [name, stats] of Object.entries(doc.data.feeds)) {
          const view = names.get(name);
          if (view) { view.silentS = stats.silent_s; view.dirty = true; }
        }
      } else names.get(doc.station)?.handle(doc);
    }
  };
  ws.onclose = (event) => {
    if (event.code === 4401) { location.assign("/login"); return; }
    status.textContent = "disconnected: reconnecting";
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
