// Line charts as inline SVG (no library, no CDN): used for the learning curves.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";

function svgEl(name, attrs, text) {
  const el = document.createElementNS(SVG_NS, name);
  for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, v);
  if (text !== undefined) el.textContent = text;
  return el;
}

// "Nice" tick values covering [lo, hi].
function niceTicks(lo, hi, count) {
  if (!(hi > lo)) { hi = lo + 1; }
  const raw = (hi - lo) / Math.max(1, count);
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw) || 10 * mag;
  const ticks = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) ticks.push(+v.toPrecision(12));
  return ticks;
}

function fmtTick(v) {
  const a = Math.abs(v);
  if (a >= 1e6) return (v / 1e6).toFixed(a >= 1e7 ? 0 : 1) + "M";
  if (a >= 1e3) return (v / 1e3).toFixed(a >= 1e4 ? 0 : 1) + "k";
  return String(+v.toFixed(2));
}

// series: [{name, color, points: [[x, y], ...]}]; opts: {title, xLabel, yLabel, yMin, yMax}
function lineChart(series, opts) {
  const W = 460, H = 240, m = { l: 56, r: 12, t: 26, b: 40 };
  const svg = svgEl("svg", { viewBox: `0 0 ${W} ${H}`, class: "chart", role: "img",
    "aria-label": opts.title || "chart" });
  const pts = series.flatMap((s) => s.points).filter((p) => Number.isFinite(p[0]) && Number.isFinite(p[1]));
  svg.appendChild(svgEl("text", { x: m.l, y: 16, class: "chart-title" }, opts.title || ""));
  if (!pts.length) {
    svg.appendChild(svgEl("text", { x: W / 2, y: H / 2, "text-anchor": "middle", class: "chart-empty" },
      "no evaluation point yet"));
    return svg;
  }
  let x0 = Math.min(...pts.map((p) => p[0])), x1 = Math.max(...pts.map((p) => p[0]));
  let y0 = opts.yMin ?? Math.min(...pts.map((p) => p[1])), y1 = opts.yMax ?? Math.max(...pts.map((p) => p[1]));
  if (x1 <= x0) { x0 -= 1; x1 += 1; }
  if (y1 <= y0) { y0 -= 1; y1 += 1; }
  const yt = niceTicks(y0, y1, 4), xt = niceTicks(x0, x1, 5);
  y0 = Math.min(y0, yt[0]); y1 = Math.max(y1, yt[yt.length - 1]);
  const X = (x) => m.l + (x - x0) / (x1 - x0) * (W - m.l - m.r);
  const Y = (y) => H - m.b - (y - y0) / (y1 - y0) * (H - m.t - m.b);
  for (const v of yt) {
    svg.appendChild(svgEl("line", { x1: m.l, x2: W - m.r, y1: Y(v), y2: Y(v), class: "grid" }));
    svg.appendChild(svgEl("text", { x: m.l - 6, y: Y(v) + 4, "text-anchor": "end", class: "tick" }, fmtTick(v)));
  }
  for (const v of xt) {
    if (v < x0 || v > x1) continue;
    svg.appendChild(svgEl("line", { x1: X(v), x2: X(v), y1: H - m.b, y2: H - m.b + 4, class: "axis" }));
    svg.appendChild(svgEl("text", { x: X(v), y: H - m.b + 16, "text-anchor": "middle", class: "tick" }, fmtTick(v)));
  }
  svg.appendChild(svgEl("line", { x1: m.l, x2: W - m.r, y1: H - m.b, y2: H - m.b, class: "axis" }));
  svg.appendChild(svgEl("line", { x1: m.l, x2: m.l, y1: m.t, y2: H - m.b, class: "axis" }));
  svg.appendChild(svgEl("text", { x: (m.l + W - m.r) / 2, y: H - 6, "text-anchor": "middle", class: "label" },
    opts.xLabel || ""));
  svg.appendChild(svgEl("text", { x: 12, y: (m.t + H - m.b) / 2, "text-anchor": "middle", class: "label",
    transform: `rotate(-90 12 ${(m.t + H - m.b) / 2})` }, opts.yLabel || ""));
  series.forEach((s, i) => {
    const p = s.points.filter((q) => Number.isFinite(q[0]) && Number.isFinite(q[1]));
    if (!p.length) return;
    const d = p.map((q, j) => `${j ? "L" : "M"}${X(q[0]).toFixed(1)},${Y(q[1]).toFixed(1)}`).join("");
    svg.appendChild(svgEl("path", { d, fill: "none", stroke: s.color, "stroke-width": 2 }));
    for (const q of p) svg.appendChild(svgEl("circle", { cx: X(q[0]), cy: Y(q[1]), r: 2.5, fill: s.color }));
    if (series.length > 1) {
      svg.appendChild(svgEl("text", { x: W - m.r - 4, y: m.t + 12 + 14 * i, "text-anchor": "end",
        class: "legend", fill: s.color }, s.name));
    }
  });
  return svg;
}

window.modsatCharts = { lineChart, niceTicks };
