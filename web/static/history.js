// Session history with filters; each row links to its session page.
import { api, el, showError, start, table } from "/static/common.js";

const form = document.querySelector("#filters");
const error = document.querySelector("#error");

async function load() {
  error.hidden = true;
  const query = new URLSearchParams();
  for (const [k, v] of new FormData(form)) if (v) query.set(k, v);
  history.replaceState(null, "", query.toString() ? `?${query}` : location.pathname);
  try {
    const rows = await api(`/api/sessions?${query}`);
    const body = rows.map((s) => [
      el("a", { href: `/sessions/${encodeURIComponent(s.uid)}` }, s.uid), s.created_utc.replace("T", " ").slice(0, 19),
      s.procedure, s.instrument_serial, el("span", { class: `status ${s.status}` }, s.status), String(s.n_points),
      s.stations.join(", ")]);
    document.querySelector("#sessions").replaceChildren(rows.length
      ? table(["session", "created (UTC)", "procedure", "instrument", "outcome", "points", "station"], body)
      : el("p", {}, "No session matches."));
  } catch (err) {
    showError(error, err);
  }
}

async function main() {
  await start("/history");
  const given = new URLSearchParams(location.search);
  const all = await api("/api/sessions?limit=1000");
  const procedures = [...new Set(all.map((s) => s.procedure))].sort();
  form.procedure.append(...procedures.map((p) => el("option", { value: p }, p)));
  for (const [k, v] of given) if (form.elements[k]) form.elements[k].value = v;
  form.addEventListener("submit", (e) => { e.preventDefault(); load(); });
  load();
}

main();
