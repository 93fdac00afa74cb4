// Shared by every page: the API with the login's CSRF token, the navigation bar, DOM and number helpers.

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
    this.detail = message; // as the API sent it: text, or an object (a start's design warnings)
  }
}

export const session = { user: null, role: null, csrf: null };

// fetch() of the panel's API: JSON in and out, the CSRF token on every POST, errors as ApiError(status, detail).
export async function api(path, { method = "GET", body, form } = {}) {
  const headers = {};
  if (method !== "GET") headers["X-CSRF-Token"] = session.csrf ?? "";
  let payload = form;
  if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    payload = JSON.stringify(body);
  }
  const r = await fetch(path, { method, headers, body: payload, credentials: "same-origin" });
  const isJson = (r.headers.get("content-type") || "").includes("json");
  const data = isJson ? await r.json() : await r.text();
  if (r.status === 401 && path !== "/api/login") location.assign("/login");
  if (!r.ok) throw new ApiError(r.status, (data && data.detail) || String(data));
  return data;
}

// An element with attributes and children (strings become text: nothing from the API is parsed as HTML).
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (k === "dataset") Object.assign(node.dataset, v);
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) if (c !== undefined && c !== null) node.append(c);
  return node;
}

export function table(head, rows) {
  return el("table", {}, el("thead", {}, el("tr", {}, head.map((h) => el("th", {}, h)))),
    el("tbody", {}, rows.map((r) => el("tr", {}, r.map((c) => el("td", {}, c))))));
}

// A two-column table of label and value.
export function facts(rows) {
  return el("table", { class: "facts" }, el("tbody", {}, rows.map(([k, v]) => el("tr", {}, el("th", {}, k), el("td", {}, v)))));
}

export function num(x, digits = 4) {
  if (x === null || x === undefined || Number.isNaN(x)) return "—";
  const a = Math.abs(x);
  if (a !== 0 && (a < 1e-3 || a >= 1e6)) return x.toExponential(digits - 1);
  const text = x.toPrecision(digits);
  return text.includes(".") ? text.replace(/\.?0+$/, "") : text; // trailing zeros of the fraction only
}

// uPlot axis labels (its `values` option) with as many significant digits as the ticks' spacing needs, so that
// neighbouring ticks read apart (0.5612341 and 0.5612342 rad/s, where 3 digits made every tick 0.561).
export function tickLabels(u, ticks) {
  const steps = ticks.slice(1).map((v, i) => Math.abs(v - ticks[i])).filter((d) => d > 0);
  if (!steps.length) return ticks.map((v) => num(v, 3));
  const top = Math.max(...ticks.map(Math.abs));
  const digits = Math.min(15, Math.max(3, Math.ceil(Math.log10(top / Math.min(...steps))) + 1));
  return ticks.map((v) => num(v, digits));
}

export function duration(s) {
  if (s === null || s === undefined || !Number.isFinite(s)) return "—";
  if (s < 60) return `${s.toFixed(s < 10 ? 1 : 0)} s`;
  const h = Math.floor(s / 3600);
  const m = Math.floor((s % 3600) / 60);
  return h ? `${h} h ${String(m).padStart(2, "0")} min` : `${m} min ${String(Math.floor(s % 60)).padStart(2, "0")} s`;
}

export function showError(box, err) {
  box.textContent = err instanceof Error ? err.message : String(err);
  box.hidden = false;
}

// Who is logged in (or off to the login page), and the navigation bar.
export async function start(active) {
  Object.assign(session, await api("/api/me"));
  const links = [["/", "Live"], ["/history", "History"], ["/gap", "Gap diagnosis"]];
  const logout = el("button", { type: "button", class: "link", onclick: async () => {
    await api("/api/logout", { method: "POST" });
    location.assign("/login");
  } }, "Log out");
  document.querySelector("nav").replaceChildren(
    el("strong", {}, "PIGA station"),
    ...links.map(([href, text]) => el("a", { href, "aria-current": href === active ? "page" : null }, text)),
    el("span", { class: "who", "data-role": session.role }, `${session.user} (${session.role})`),
    logout,
  );
  document.body.dataset.role = session.role;
  return session;
}

// A uPlot chart that follows its container's width (down to a phone's 360 px screen).
export function chart(container, opts, data) {
  const width = () => Math.max(container.clientWidth, 200);
  const plot = new uPlot({ width: width(), height: 220, ...opts }, data, container);
  new ResizeObserver(() => plot.setSize({ width: width(), height: plot.height })).observe(container);
  return plot;
}

// Links to the session's certificate (HTML and PDF) appended to `box` once it is known that its analysis issued one.
export function appendCertificateLinks(box, uid) {
  const base = `/api/sessions/${encodeURIComponent(uid)}`;
  return fetch(`${base}/certificate`, { credentials: "same-origin" }).then((r) => {
    if (!r.ok) return; // the procedure issues no certificate
    box.append(el("a", { href: `${base}/certificate`, target: "_blank", class: "certificate-link" }, "certificate"),
      el("a", { href: `${base}/certificate.pdf`, class: "certificate-pdf" }, "certificate (PDF)"));
  }).catch(() => {});
}

export const UNCERTAINTY_NOTE = "u: standard uncertainty (k = 1, about 68 %), the GUM budget's (Type A and B) " +
  "where the method has one, else the least-squares fit's (seed 000 eq. 22); U = k u: expanded uncertainty with " +
  "its coverage factor k (Student's t at the effective degrees of freedom, about 95 %), shown where the method " +
  "states it.";

// Every quantity with a value in a method's results, in either shape the methods write:
// {coefficients: {name: {value, sigma, ...}}, units: {name: unit}} or {name: {value, sigma, unit}}, at any depth
// (lists of per-block results too); a quantity stated twice in one block (plain, then with its GUM budget) once.
// The same reading as station/coefficients.py (coefficient_rows, suffix_unit), for the browser.
const SUFFIX_UNITS = [["_g_per_s", "g/s"], ["_radps", "rad/s"], ["_mps2", "m/s^2"], ["_arcsec", "arcsec"],
  ["_ppm", "ppm"], ["_rad", "rad"], ["_deg", "deg"], ["_hz", "Hz"], ["_m", "m"], ["_s", "s"], ["_g", "g"],
  ["_v", "V"], ["_c", "°C"]];

export function suffixUnit(...names) {
  if (names.length && names[0].toLowerCase().endsWith("_per_s")) {
    return `${suffixUnit(names[0].slice(0, -"_per_s".length), ...names.slice(1)) || "1"}/s`;
  }
  for (const name of names) {
    const hit = SUFFIX_UNITS.find(([suffix]) => name.toLowerCase().endsWith(suffix));
    if (hit) return hit[1];
  }
  return "";
}

// k = t_0.975(nu): Student's t at a whole number nu of degrees of freedom (a fit's n - p), as
// station.coefficients.student_k: P(|T| < t) in closed form (Abramowitz and Stegun 26.7.3-4), inverted by bisection.
export function studentK(nu) {
  if (!Number.isInteger(nu) || nu < 1) return null;
  const within = (t) => {
    const th = Math.atan(t / Math.sqrt(nu));
    const c2 = Math.cos(th) ** 2;
    const odd = nu % 2 === 1;
    let term = 1, sum = 1;
    for (let m = 1; m <= (odd ? (nu - 3) / 2 : (nu - 2) / 2); m++) {
      term *= c2 * (odd ? (2 * m) / (2 * m + 1) : (2 * m - 1) / (2 * m));
      sum += term;
    }
    return odd ? (2 / Math.PI) * (th + (nu > 1 ? Math.sin(th) * Math.cos(th) * sum : 0)) : Math.sin(th) * sum;
  };
  let lo = 0, hi = 1e3;
  for (let i = 0; i < 200 && hi - lo > 1e-15 * hi; i++) {
    const mid = 0.5 * (lo + hi);
    if (within(mid) < 0.95) lo = mid; else hi = mid;
  }
  return 0.5 * (lo + hi);
}

function* walkQuantities(doc, where, units, dof) {
  const isNumber = (x) => typeof x === "number" && Number.isFinite(x);
  const own = doc && typeof doc.units === "object" && !Array.isArray(doc.units) ? doc.units : {};
  const u = { ...units, ...own };
  const nu = doc && isNumber(doc.dof) && doc.dof > 0 ? doc.dof : dof; // the fit's residual dof at this level or above
  for (const [key, item] of Object.entries(doc || {})) {
    if (Array.isArray(item)) {
      for (const [i, element] of item.entries()) {
        if (element && typeof element === "object" && !Array.isArray(element)) {
          yield* walkQuantities(element, where ? `${where}.${key}[${i}]` : `${key}[${i}]`, u, nu);
        }
      }
      continue;
    }
    if (!item || typeof item !== "object" || key === "units") continue;
    if (key === "coefficients") { yield* walkQuantities(item, where, u, nu); continue; }
    if ("value" in item && (item.value === null || isNumber(item.value))) {
      const budget = isNumber(item.standard_uncertainty) && isNumber(item.expanded_uncertainty) && isNumber(item.coverage_factor);
      const sigma = isNumber(item.sigma) ? item.sigma : null;
      const std = budget ? item.standard_uncertainty : sigma;
      const k = budget ? item.coverage_factor : nu === null ? null : studentK(nu); // never a fixed k
      const unit = item.unit || u[key] || suffixUnit(key, where.split(".").at(-1) || "");
      yield { result: where || key, name: key, value: item.value, u: std, k, unit,
        expanded: budget ? item.expanded_uncertainty : std === null || k === null ? null : k * std,
        note: item.note || "", budget };
    } else yield* walkQuantities(item, where ? `${where}.${key}` : key, u, nu);
  }
}

const blockOf = (path) => (path.lastIndexOf("]") >= 0 ? path.slice(0, path.lastIndexOf("]") + 1) : path.split(".")[0]);

export function coefficientRows(results) {
  const best = new Map();
  for (const row of walkQuantities(results, "", {}, null)) {
    const key = `${blockOf(row.result)}\u0000${row.name}`;
    const old = best.get(key);
    const rank = (r) => 2 * Number(r.budget) + Number(Boolean(r.unit));
    if (!old) best.set(key, row);
    else if (rank(row) > rank(old)) best.set(key, { ...row, result: old.result });
  }
  return [...best.values()];
}
