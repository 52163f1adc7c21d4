// An HTTP answer as the page reads it: its JSON, and for a failure the server's reason. FastAPI's
// errors are JSON ({"detail": ...}); the request guard's refusals (403, 413) are plain text, which
// the page showed as "HTTP 403", hiding why.
"use strict";

// {data, message}: data the parsed JSON ({} when the body is none), message "" when res.ok, else
// the detail, each validation error as "field: why", the plain-text reason, or "HTTP <status>".
async function readAnswer(res) {
  const text = await res.text().catch(() => "");
  let data = null;
  try { data = text ? JSON.parse(text) : {}; } catch { data = null; }
  if (res.ok) return { data: data ?? {}, message: "" };
  const d = data?.detail;
  const message = typeof d === "string" ? d
    : Array.isArray(d) ? d.map((x) => `${(x.loc || []).slice(1).join(".")}: ${x.msg}`).join("; ")
    : data === null && text.trim() ? text.trim().split("\n")[0].slice(0, 300)
    : `HTTP ${res.status}`;
  return { data: data ?? {}, message };
}
