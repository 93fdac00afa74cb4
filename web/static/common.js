// Shared by every page: the API with the login's CSRF token, the navigation bar, DOM and number helpers.

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
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
  return a !== 0 && (a < 1e-3 || a >= 1e6) ? x.toExponential(digits - 1) : x.toPrecision(digits).replace(/\.?0+$/, "");
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

// A uPlot chart that follows its container's width.
export function chart(container, opts, data) {
  const plot = new uPlot({ width: Math.max(container.clientWidth, 300), height: 220, ...opts }, data, container);
  new ResizeObserver(() => plot.setSize({ width: Math.max(container.clientWidth, 300), height: plot.height }))
    .observe(container);
  return plot;
}
