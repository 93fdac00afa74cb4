// A session: summary, coefficients with uncertainties, residual plots, timing capture, events, report and download.
import { api, appendCertificateLinks, chart, coefficientRows, el, facts, num, session as me, showError, start, table, tickLabels, UNCERTAINTY_NOTE } from "/static/common.js";

const uid = decodeURIComponent(location.pathname.split("/").pop());
const error = document.querySelector("#error");
const $ = (id) => document.querySelector(id);

function coefficientTables(results) {
  if (!results.length) return [el("p", {}, "No results stored (the session is running, aborted, or its analysis failed).")];
  const sections = results.map(({ method, result }) => {
    const found = coefficientRows({ [method]: result });
    if (!found.length) return el("pre", {}, JSON.stringify(result, null, 2));
    const rows = found.map((r) => [r.name, r.unit || "—", r.value === null ? `not identified${r.note ? ` (${r.note})` : ""}` : num(r.value, 7),
      r.u === null ? "—" : num(r.u, 3), num(r.k, 3), r.expanded === null ? "—" : num(r.expanded, 3)]);
    const extra = [Number.isFinite(result.sigma_residual) ? `σ residual ${num(result.sigma_residual, 4)} rad/s` : null,
      Number.isFinite(result.mu) ? `μ ${num(result.mu, 3)} vs μc ${num(result.mu_c, 3)}` : null,
      result.reliable === undefined ? null : result.reliable ? "accepted (no outlier, eq. 28)" : "possible outlier (eq. 28)",
      result.n_points !== undefined ? `${result.n_points} points, ${result.dof} dof` : null].filter(Boolean).join("; ");
    return el("section", { class: "method" }, el("h3", {}, method),
      el("div", { class: "scroll" }, table(["coefficient", "unit", "value", "u (k = 1)", "k", "U = k u"], rows)), el("p", {}, extra));
  });
  return [...sections, el("p", {}, el("small", {}, UNCERTAINTY_NOTE))];
}

function residualCharts(residuals) {
  const box = $("#residuals");
  const methods = Object.entries(residuals).filter(([, r]) => !r.error);
  const notes = Object.entries(residuals).filter(([, r]) => r.error).map(([m, r]) => el("p", {}, `${m}: ${r.error}`));
  box.replaceChildren(...notes);
  if (!methods.length) return;
  const n = methods[0][1].residuals_radps.length;
  const x = Array.from({ length: n }, (_, i) => i + 1);
  const colours = ["#1565c0", "#c62828", "#2e7d32"];
  const decades = (u, ticks) => ticks.map((v) => num(v, 2)); // a log axis: its ticks are a decade's steps
  // Each method on its own scale: the baseline's residuals are about 1000 times the integral method's.
  for (const [title, key, unit, log] of [["Residuals e", "residuals_radps", "rad/s", false],
    ["Proportional residuals |e / (a cos θ)|", "proportional_residuals", "rad/s/g", true]]) {
    const holder = el("div", { class: "chart", dataset: { chart: key } });
    box.append(holder);
    const series = methods.map(([m], i) => ({ label: `${m} (${unit})`, scale: m, stroke: colours[i % colours.length],
      points: { show: true } }));
    const scales = { x: { time: false } };
    for (const [m] of methods) scales[m] = log ? { distr: 3 } : {};
    const axes = [{ label: "vibration point" }, ...methods.map(([m], i) => ({ scale: m, side: i ? 1 : 3, size: 80,
      label: `${m} (${unit})`, values: log ? decades : tickLabels, stroke: colours[i % colours.length], grid: { show: i === 0 } }))];
    const ys = methods.map(([, r]) => r[key].map((v) => (log ? Math.abs(v) : v)));
    chart(holder, { title, scales, axes, series: [{ label: "vibration point" }, ...series] }, [x, ...ys]);
  }
}

function timingTable(points) {
  const rows = points.map((p) => [p.point_id, num(p.position_deg, 6), p.kind === "static" ? "static" : num(p.freq_hz, 4),
    String(p.pulses), p.Np ?? "—", p.t1_s === null ? "—" : p.t1_s.toFixed(7), p.Tm_s.toFixed(6),
    p.t2_s === null ? "—" : p.t2_s.toFixed(7)]);
  return table(["point", "position (deg)", "f (Hz)", "pulses", "Np", "t1 (s)", "Tm (s)", "t2 (s)"], rows);
}

async function main() {
  await start("/history");
  const rec = await api(`/api/sessions/${encodeURIComponent(uid)}`);
  const s = rec.session;
  document.title = `Session ${uid} — PIGA station panel`;
  $("#title").textContent = `Session ${uid}`;
  const base = `/api/sessions/${encodeURIComponent(uid)}`;
  const links = [el("a", { href: `${base}/report`, target: "_blank", id: "report-link" }, "HTML report"),
    el("a", { href: `${base}/export`, download: `session-${uid}.zip`, class: "export-link" }, "piga-session/1 download"),
    el("a", { href: `/gap?uid=${encodeURIComponent(uid)}` }, "gap diagnosis")];
  if (me.role === "operator" && ["aborted", "failed"].includes(s.status)) {
    links.push(el("button", { type: "button", onclick: async () => {
      try {
        await api(`/api/stations/${s.stations[0]}/resume-session`, { method: "POST", body: { uid } });
        location.assign("/");
      } catch (err) { showError(error, err); }
    } }, "Resume this session"));
  }
  $("#links").replaceChildren(...links);
  appendCertificateLinks($("#links"), uid);
  const params = rec.config.params ? Object.entries(rec.config.params).map(([k, v]) => `${k} = ${JSON.stringify(v)}`).join("; ") : "—";
  $("#summary").replaceChildren(facts([["procedure", s.procedure], ["instrument", s.instrument_serial || "—"],
    ["outcome", el("span", { class: `status ${s.status}` }, s.status)], ["created (UTC)", s.created_utc],
    ["points", String(s.n_points)], ["station", s.stations.join(", ")], ["parameters", params]]));
  $("#coefficients").replaceChildren(...coefficientTables(rec.results));
  $("#timing").replaceChildren(timingTable(rec.points));
  $("#events").replaceChildren(table(["time (UTC)", "level", "kind", "message"],
    rec.events.map((e) => [e.t_utc.replace("T", " ").slice(0, 23), e.level, e.kind, e.message])));
  residualCharts(await api(`${base}/residuals`));
}

main().catch((err) => showError(error, err));
