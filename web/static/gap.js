// Gap diagnosis of a stored session (?uid=) or an uploaded piga-session/1 zip: verdict, shrink, effects, maps.
import { api, duration, el, num, showError, start, table } from "/static/common.js";

const $ = (id) => document.querySelector(id);
const error = $("#error");
const busy = $("#busy");

function heldOut(r, shrink) {
  return table(["held-out gap", "value", "standard error if no gap"], [
    ["twin (calibrated coefficients refitted)", num(r.gap_before.value, 3), num(r.gap_before.standard_error_if_no_gap, 3)],
    ["with the chosen effect(s)", num(r.gap_after.value, 3), num(r.gap_after.standard_error_if_no_gap, 3)],
    ["shrink", shrink === null ? "no held-out gap to shrink" : `${(100 * shrink).toFixed(0)} %`, ""]]);
}

function candidates(r) {
  const fmtParams = (c) => Object.entries(c.parameters || {}).map(([k, v]) =>
    `${k} = ${num(v, 4)} ± ${num(c.uncertainty?.[k], 2)} ${c.units?.[k] ?? ""}`).join("; ");
  return table(["rank", "effect", "cause", "identifiable", "accepted", "parameters", "ΔBIC", "held-out shrink"],
    r.candidates.map((c) => [c.rank ?? "—", c.name, c.cause, c.identifiable ? "yes" : "no", c.accepted ? "yes" : "",
      fmtParams(c), c.evidence ? num(c.evidence.delta_bic, 3) : "—", c.heldout_shrink === null ? "—" : num(c.heldout_shrink, 3)]));
}

function maps(r) {
  const m = r.where.maps;
  const rowsOf = (list, key) => list.map((g) => [String(g[key]), String(g.n), num(g.mean_z, 3), num(g.rms_z, 3), num(g.p_value, 3)]);
  const head = (what) => [what, "points", "mean z", "rms z", "p"];
  const freqs = [...new Set(m.grid.map((g) => g.freq_hz))].sort((a, b) => a - b);
  const positions = [...new Set(m.grid.map((g) => g.position_deg))].sort((a, b) => a - b);
  const cell = (p, f) => {
    const zs = m.grid.filter((g) => g.position_deg === p && g.freq_hz === f).map((g) => g.z);
    if (!zs.length) return el("td", {}, "");
    const z = zs.reduce((a, b) => a + b, 0) / zs.length;
    const shade = Math.min(Math.abs(z) / 3, 1);
    const colour = z > 0 ? `rgba(198,40,40,${shade})` : `rgba(21,101,192,${shade})`;
    return el("td", { style: `background:${colour}`, title: `z = ${z}` }, num(z, 2));
  };
  const grid = el("table", { class: "map" },
    el("thead", {}, el("tr", {}, el("th", {}, "position \\ f (Hz)"), freqs.map((f) => el("th", {}, f === 0 ? "static" : num(f, 3))))),
    el("tbody", {}, positions.map((p) => el("tr", {}, el("th", {}, `${num(p, 5)}°`), freqs.map((f) => cell(p, f))))));
  return [el("h3", {}, "Standardised residuals by position and frequency"), grid,
    el("h3", {}, "By position"), table(head("position (deg)"), rowsOf(m.by_position, "position_deg")),
    el("h3", {}, "By frequency"), table(head("f (Hz)"), rowsOf(m.by_frequency, "freq_hz")),
    el("h3", {}, "By time block"), table(head("block"), rowsOf(m.by_time_block, "block"))];
}

// Which session the diagnosis is of: its uid (linked to its page where it is stored), procedure, instrument, points.
function diagnosed(s, id) {
  const name = s.uid ? el("a", { href: `/sessions/${encodeURIComponent(s.uid)}` }, s.uid) : "an uploaded session";
  const what = [s.procedure, s.instrument_serial && `instrument ${s.instrument_serial}`,
    s.created_utc && `created ${s.created_utc.replace("T", " ").slice(0, 19)} UTC`, `${s.n_points} points`].filter(Boolean);
  return el("p", { id: "diagnosed", dataset: { uid: s.uid || "", gap: id } }, "Diagnosis of session ", name, ` (${what.join(", ")})`);
}

function show({ id, session: s, report: r, shrink }) {
  $("#result").replaceChildren(diagnosed(s, id),
    el("h2", {}, "Verdict: ", el("span", { class: `verdict ${r.verdict}`, id: "verdict" }, r.verdict)),
    el("p", {}, r.verdict_text),
    el("p", {}, el("a", { href: `/api/gap/${encodeURIComponent(id)}/report`, target: "_blank" }, "full HTML report")),
    el("h2", {}, "Held-out gap and its shrink"), heldOut(r, shrink),
    el("h2", {}, "Where the gap lies"), el("p", {}, r.where.summary), ...maps(r),
    el("h2", {}, "Ranked effects"), candidates(r));
}

// While a diagnosis runs (one request, seconds to a minute of CPU): what is diagnosed, the time so far, and the
// last diagnosis's time on this panel as the only honest expectation.
async function run(what, promise) {
  error.hidden = true;
  $("#result").replaceChildren();
  const status = await api("/api/gap/status").catch(() => ({ last_elapsed_s: null }));
  const expected = status.last_elapsed_s;
  const t0 = performance.now();
  const bar = el("div", { class: "bar-fill" });
  const line = el("span", {});
  busy.replaceChildren(line, expected ? el("div", { class: "bar small" }, bar) : "");
  const tick = () => {
    const elapsed = (performance.now() - t0) / 1000;
    line.textContent = `Diagnosing ${what}: ${duration(elapsed)} so far; ` + (expected
      ? `the last diagnosis on this panel took ${duration(expected)}.`
      : "a diagnosis refits the twin with every candidate effect, some tens of seconds of CPU.");
    if (expected) bar.style.width = `${Math.min(100, (100 * elapsed) / expected).toFixed(0)}%`;
    busy.dataset.elapsedS = elapsed.toFixed(1);
  };
  tick();
  const timer = setInterval(tick, 500);
  busy.hidden = false;
  try {
    show(await promise);
  } catch (err) {
    showError(error, err);
  } finally {
    clearInterval(timer);
    busy.hidden = true;
  }
}

async function main() {
  await start("/gap");
  const uid = new URLSearchParams(location.search).get("uid");
  const form = $("#upload");
  form.addEventListener("submit", (e) => {
    e.preventDefault();
    run(`the uploaded ${form.archive.files[0]?.name ?? "session"}`, api("/api/gap", { method: "POST", form: new FormData(form) }));
  });
  if (uid) run(`session ${uid}`, api(`/api/sessions/${encodeURIComponent(uid)}/gap`));
}

main();
