"""The page at ``/``: a plain list of jobs read from the API (the web UI is a later issue)."""

INDEX_HTML = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>modsat jobs</title>
<style>
  body { font: 14px/1.4 system-ui, sans-serif; margin: 2em; color: #222; }
  table { border-collapse: collapse; margin-top: 1em; }
  th, td { padding: 4px 10px; border-bottom: 1px solid #ddd; text-align: left; }
  td.num { text-align: right; font-variant-numeric: tabular-nums; }
  .failed { color: #b00; } .succeeded { color: #070; } .running { color: #06c; }
  code { background: #f4f4f4; padding: 1px 4px; }
</style>
</head>
<body>
<h1>modsat jobs</h1>
<p>This page only lists the jobs stored in this service, refreshed every 2 seconds; the web
interface comes later. Submit runs with <code>POST /api/jobs</code> (for example
<code>{"preset": "quick"}</code>). API reference: <a href="/api/openapi.json">/api/openapi.json</a>
(interactive, if this browser can reach the Swagger UI files: <a href="/api/docs">/api/docs</a>).</p>
<p id="info">loading...</p>
<table>
<thead><tr><th>id</th><th>name</th><th>algorithm</th><th>status</th><th>env steps</th>
<th>progress</th><th>last eval return</th><th>error</th><th>files</th></tr></thead>
<tbody id="rows"></tbody>
</table>
<script>
function cell(tr, text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  tr.appendChild(td);
  return td;
}
async function refresh() {
  try {
    const r = await fetch("/api/jobs?limit=100");
    const page = await r.json();
    const rows = document.getElementById("rows");
    rows.replaceChildren();
    for (const j of page.items) {
      const tr = document.createElement("tr");
      cell(tr, j.id, "num");
      cell(tr, j.name || "");
      cell(tr, j.algorithm);
      cell(tr, j.status + (j.cancel_requested && j.status === "running" ? " (cancelling)" : ""), j.status);
      cell(tr, j.progress.env_steps.toLocaleString() + " / " + j.progress.total_env_steps.toLocaleString(), "num");
      cell(tr, (100 * j.progress.fraction).toFixed(0) + " %", "num");
      cell(tr, j.last_eval && j.last_eval.mean_return != null ? j.last_eval.mean_return.toFixed(1) : "", "num");
      cell(tr, j.error || "");
      const a = document.createElement("a");
      a.href = j.url + "/artifacts";
      a.textContent = "artefacts";
      cell(tr, "").appendChild(a);
      rows.appendChild(tr);
    }
    document.getElementById("info").textContent =
      page.total + " job(s); showing the newest " + page.items.length + ".";
  } catch (e) {
    document.getElementById("info").textContent = "cannot reach the API: " + e;
  }
}
refresh();
setInterval(refresh, 2000);
</script>
</body>
</html>
"""
