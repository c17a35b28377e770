// Talking to the service: the bearer token (kept for this tab only) and readable errors.

const TOKEN_KEY = "dlo-viewer-token";

export function token() {
  try {
    return sessionStorage.getItem(TOKEN_KEY) || "";
  } catch {
    return ""; // storage disabled: the token lives in the form only
  }
}

export function setToken(value) {
  try {
    if (value) sessionStorage.setItem(TOKEN_KEY, value);
    else sessionStorage.removeItem(TOKEN_KEY);
  } catch {
    // storage disabled: nothing to keep
  }
}

export function authHeaders() {
  const value = token();
  return value ? { Authorization: `Bearer ${value}` } : {};
}

const TITLES = {
  400: "Bad request",
  401: "This service needs its token (DLO_API_TOKEN): enter it at the top right",
  404: "Not found",
  413: "Too large for this service",
  415: "Not an image type the service takes (PNG or JPEG)",
  422: "The service cannot use this input",
  500: "The service failed on this input",
  503: "The service cannot take it now",
};

// An error the page shows: {status, title, detail}.
export function problem(status, detail, code = "") {
  const title = TITLES[status] || `Error ${status}`;
  return { status, code, title, detail: detail || "" };
}

// The service's JSON error ({status, error, detail}) of a failed response, made readable.
export async function responseProblem(response) {
  let detail = "";
  let code = "";
  try {
    const body = await response.json();
    detail = typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail);
    code = body.error || "";
  } catch {
    detail = response.statusText;
  }
  const retry = response.headers.get("Retry-After");
  if (retry) detail += ` (retry after ${retry} s)`;
  return problem(response.status, detail, code);
}

export function networkProblem(error) {
  return problem(0, `the service cannot be reached: ${error.message || error}`);
}

export function showProblem(element, found) {
  element.classList.remove("info");
  element.replaceChildren();
  const strong = document.createElement("strong");
  strong.textContent = found.status ? `${found.status} · ${found.title}` : found.title || "Error";
  element.append(strong);
  if (found.detail) element.append(document.createElement("br"), found.detail);
  element.hidden = false;
  element.dataset.status = String(found.status || "");
}

export function showInfo(element, text) {
  element.classList.add("info");
  element.textContent = text;
  element.hidden = false;
  element.dataset.status = "";
}

export function hideMessage(element) {
  element.hidden = true;
  element.replaceChildren();
  element.dataset.status = "";
}
