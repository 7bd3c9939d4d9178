// Inline SVG drawings (no library, no CDN, no WebGL): line charts for the learning curves, and
// the small isometric picture of a satellite's design in the job list.
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

// Labels of one axis's ticks: one unit (k, M) for the axis, and as many decimals as it takes for
// neighbouring ticks to read differently ("6.65k 6.66k 6.67k", never "6.7k" six times).
function tickLabels(ticks) {
  const big = Math.max(0, ...ticks.map(Math.abs));
  const [div, unit] = big >= 1e6 ? [1e6, "M"] : big >= 1e3 ? [1e3, "k"] : [1, ""];
  const step = ticks.length > 1 ? Math.abs(ticks[1] - ticks[0]) / div : 1;
  let d = Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
  const exact = (k) => ticks.every((v) => Math.abs(v / div * 10 ** k - Math.round(v / div * 10 ** k)) < 1e-6);
  while (d < 6 && !exact(d)) d++;  // a step of 25 shows 1.175k, not 1.18k
  for (; d <= 6; d++) {
    const labels = ticks.map((v) => String(+(v / div).toFixed(d)) + (v === 0 ? "" : unit));
    if (new Set(labels).size === labels.length) return labels;
  }
  return ticks.map((v) => String(v));
}

// The frame of a chart: y grid lines and ticks, x ticks, the two axes and their labels.
// a: {W, H, m (margins), X, Y (data to pixels), xt, yt (ticks), xLabel, yLabel, xLabelY}.
function drawAxes(svg, a) {
  const { W, H, m, X, Y } = a;
  const yl = tickLabels(a.yt), xl = tickLabels(a.xt);
  a.yt.forEach((v, i) => {
    svg.appendChild(svgEl("line", { x1: m.l, x2: W - m.r, y1: Y(v), y2: Y(v), class: "grid" }));
    svg.appendChild(svgEl("text", { x: m.l - 6, y: Y(v) + 4, "text-anchor": "end", class: "tick y-tick" }, yl[i]));
  });
  a.xt.forEach((v, i) => {
    svg.appendChild(svgEl("line", { x1: X(v), x2: X(v), y1: H - m.b, y2: H - m.b + 4, class: "axis" }));
    svg.appendChild(svgEl("text", { x: X(v), y: H - m.b + 16, "text-anchor": "middle", class: "tick x-tick" }, xl[i]));
  });
  svg.appendChild(svgEl("line", { x1: m.l, x2: W - m.r, y1: H - m.b, y2: H - m.b, class: "axis" }));
  svg.appendChild(svgEl("line", { x1: m.l, x2: m.l, y1: m.t, y2: H - m.b, class: "axis" }));
  svg.appendChild(svgEl("text", { x: (m.l + W - m.r) / 2, y: a.xLabelY, "text-anchor": "middle", class: "label" },
    a.xLabel || ""));
  svg.appendChild(svgEl("text", { x: 12, y: (m.t + H - m.b) / 2, "text-anchor": "middle", class: "label",
    transform: `rotate(-90 12 ${(m.t + H - m.b) / 2})` }, a.yLabel || ""));
}

// series: [{name, color, points: [[x, y], ...]}]; opts: {title, xLabel, yLabel, yMin, yMax, refs}
// refs: [{name, value, color, dash}]: horizontal reference lines (e.g. the PD baseline) across
// the plot, inside the y range, each named in the legend under the plot.
function lineChart(series, opts) {
  const refs = (opts.refs || []).filter((r) => Number.isFinite(r.value));
  const legend = [...(series.length > 1 || refs.length ? series : []), ...refs];
  const W = 460, m = { l: 56, r: 12, t: 26, b: 40 + (legend.length ? 6 + 16 * legend.length : 0) }, H = 200 + m.b;
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
  const ys = [...pts.map((p) => p[1]), ...refs.map((r) => r.value)];
  let y0 = opts.yMin ?? Math.min(...ys), y1 = opts.yMax ?? Math.max(...ys);
  if (x1 <= x0) { x0 -= 1; x1 += 1; }
  if (y1 <= y0) { y0 -= 1; y1 += 1; }
  const yt = niceTicks(y0, y1, 4), xt = niceTicks(x0, x1, 5);
  if (yt.length > 1) {  // a free axis ends on ticks outside the data: no line on the frame's edge
    const step = yt[1] - yt[0];
    if (opts.yMax == null && yt[yt.length - 1] < y1 - step * 1e-9) yt.push(+(yt[yt.length - 1] + step).toPrecision(12));
    if (opts.yMin == null && yt[0] > y0 + step * 1e-9) yt.unshift(+(yt[0] - step).toPrecision(12));
  }
  y0 = Math.min(y0, yt[0]); y1 = Math.max(y1, yt[yt.length - 1]);
  const X = (x) => m.l + (x - x0) / (x1 - x0) * (W - m.l - m.r);
  const Y = (y) => H - m.b - (y - y0) / (y1 - y0) * (H - m.t - m.b);
  const xLabelY = H - m.b + 34;
  drawAxes(svg, { W, H, m, X, Y, xt: xt.filter((v) => v >= x0 && v <= x1), yt, xLabel: opts.xLabel,
    yLabel: opts.yLabel, xLabelY });
  for (const r of refs) {  // under the curves
    svg.appendChild(svgEl("line", { x1: m.l, x2: W - m.r, y1: Y(r.value), y2: Y(r.value), class: "ref",
      stroke: r.color, "stroke-dasharray": r.dash || "6 4", "data-value": r.value, "data-name": r.name }));
  }
  series.forEach((s) => {
    const p = s.points.filter((q) => Number.isFinite(q[0]) && Number.isFinite(q[1]));
    if (!p.length) return;
    const d = p.map((q, j) => `${j ? "L" : "M"}${X(q[0]).toFixed(1)},${Y(q[1]).toFixed(1)}`).join("");
    svg.appendChild(svgEl("path", { d, fill: "none", stroke: s.color, "stroke-width": 2, class: "series",
      "data-name": s.name }));
    for (const q of p) svg.appendChild(svgEl("circle", { cx: X(q[0]), cy: Y(q[1]), r: 2.5, fill: s.color }));
  });
  legend.forEach((s, i) => {  // a sample of the line, then its name
    const y = xLabelY + 8 + 16 * (i + 1) - 4;
    svg.appendChild(svgEl("line", { x1: m.l, x2: m.l + 24, y1: y - 4, y2: y - 4, stroke: s.color,
      "stroke-width": "value" in s ? 1.5 : 2, "stroke-dasharray": "value" in s ? (s.dash || "6 4") : "none" }));
    svg.appendChild(svgEl("text", { x: m.l + 30, y, class: "legend", fill: "#3b4453" }, s.name));
  });
  return svg;
}

// A voxel design (grid[x][y][z]: 0 empty, 1 structure, 2 and above a wheel unit) drawn isometric as inline SVG.
// Only the three faces turned to the viewer are drawn, back to front. Structure is translucent
// glass and its faces between two structure cells are left out, so an actuator inside a full
// cube still shows in its orange through one pane (the 3D view does the same).
const THUMB_COLORS = {
  1: ["#c9ced6", "#a7aeb9", "#8c94a1"],  // structure: top, +x, +y faces
  2: ["#ffa54f", "#ff7f0e", "#d9650a"],  // actuator (web.viewer.scene's orange)
};

function designThumb(grid, opts) {
  const n = grid.length, c = Math.cos(Math.PI / 6);
  const P = (x, y, z) => [(x - y) * c, (x + y) * 0.5 - z];
  const at = (x, y, z) => (x < n && y < grid[x].length && z < grid[x][y].length ? grid[x][y][z] : 0);
  const cells = [];
  for (let x = 0; x < n; x++) for (let y = 0; y < grid[x].length; y++) for (let z = 0; z < grid[x][y].length; z++) {
    if (grid[x][y][z]) cells.push([x, y, z, Math.min(grid[x][y][z], 2)]);  // every wheel type draws as a unit
  }
  cells.sort((a, b) => (a[0] + a[1] + a[2]) - (b[0] + b[1] + b[2]) || a[2] - b[2]);
  const faces = [], all = [];
  let act = 0, str = 0;
  for (const [x, y, z, t] of cells) {
    if (t === 2) act++; else str++;
    const quads = [  // [neighbour, corners]
      [at(x, y, z + 1), [P(x, y, z + 1), P(x + 1, y, z + 1), P(x + 1, y + 1, z + 1), P(x, y + 1, z + 1)]],
      [at(x + 1, y, z), [P(x + 1, y, z), P(x + 1, y + 1, z), P(x + 1, y + 1, z + 1), P(x + 1, y, z + 1)]],
      [at(x, y + 1, z), [P(x, y + 1, z), P(x + 1, y + 1, z), P(x + 1, y + 1, z + 1), P(x, y + 1, z + 1)]],
    ];
    quads.forEach(([nb, q], i) => {
      if (t !== 2 && nb === 1) return;  // glass against glass: no inner pane
      all.push(...q);
      faces.push([q, THUMB_COLORS[t === 2 ? 2 : 1][i], t === 2 ? "a" : "s"]);
    });
  }
  const label = `design: ${str} structure, ${act} actuator${act === 1 ? "" : "s"}`;
  if (!faces.length) return null;
  const xs = all.map((p) => p[0]), ys = all.map((p) => p[1]);
  const x0 = Math.min(...xs), y0 = Math.min(...ys);
  const span = Math.max(Math.max(...xs) - x0, Math.max(...ys) - y0) || 1, pad = span * 0.04;
  const k = 100 / (span + 2 * pad);  // to a 100 x 100 view box, centred
  const ox = (100 - (Math.max(...xs) - x0) * k) / 2, oy = (100 - (Math.max(...ys) - y0) * k) / 2;
  const svg = svgEl("svg", { viewBox: "0 0 100 100", class: "thumb " + ((opts && opts.class) || ""),
    role: "img", "aria-label": label, "data-actuators": act, "data-structure": str });
  svg.appendChild(svgEl("title", {}, label));
  for (const [q, fill, cls] of faces) {
    const pts = q.map((p) => `${(ox + (p[0] - x0) * k).toFixed(2)},${(oy + (p[1] - y0) * k).toFixed(2)}`).join(" ");
    svg.appendChild(svgEl("polygon", { points: pts, fill, class: cls }));
  }
  return svg;
}

// The trade-off (curve.json's front and its candidates): mass (kg) against median settling (s), each
// front point a button (data-index); the requirements' budget and time limit as dashed lines.
// opts: {massBudget, settlingLimit, onPick(index)}.
function frontChart(front, candidates, opts) {
  const W = 460, H = 260, m = { l: 56, r: 12, t: 26, b: 44 };
  const svg = svgEl("svg", { viewBox: `0 0 ${W} ${H}`, class: "chart front-chart", role: "img",
    "aria-label": "trade-off: mass against median settling time" });
  svg.appendChild(svgEl("text", { x: m.l, y: 16, class: "chart-title" }, "Trade-off: mass against settling time"));
  const all = [...candidates, ...front];
  const xs = all.map((p) => p.mass_kg), ys = all.map((p) => p.median_settling_s);
  if (Number.isFinite(opts.massBudget)) xs.push(opts.massBudget);
  if (Number.isFinite(opts.settlingLimit)) ys.push(opts.settlingLimit);
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(0, ...ys), y1 = Math.max(...ys);
  if (x1 <= x0) { x0 -= 1; x1 += 1; }
  if (y1 <= y0) { y1 = y0 + 1; }
  const xt = niceTicks(x0, x1, 5), yt = niceTicks(y0, y1, 4);
  x0 = Math.min(x0, xt[0]); x1 = Math.max(x1, xt[xt.length - 1]); y1 = Math.max(y1, yt[yt.length - 1]);
  const X = (x) => m.l + (x - x0) / (x1 - x0) * (W - m.l - m.r);
  const Y = (y) => H - m.b - (y - y0) / (y1 - y0) * (H - m.t - m.b);
  drawAxes(svg, { W, H, m, X, Y, xt, yt, xLabel: "total mass (kg)", yLabel: "median settling (s)", xLabelY: H - 8 });
  if (Number.isFinite(opts.massBudget)) {
    svg.appendChild(svgEl("line", { x1: X(opts.massBudget), x2: X(opts.massBudget), y1: m.t, y2: H - m.b,
      class: "ref budget", stroke: "#b54", "stroke-dasharray": "6 4" }));
  }
  if (Number.isFinite(opts.settlingLimit)) {
    svg.appendChild(svgEl("line", { x1: m.l, x2: W - m.r, y1: Y(opts.settlingLimit), y2: Y(opts.settlingLimit),
      class: "ref limit", stroke: "#b54", "stroke-dasharray": "6 4" }));
  }
  for (const p of candidates) {
    svg.appendChild(svgEl("circle", { cx: X(p.mass_kg), cy: Y(p.median_settling_s), r: 3, fill: "#bab0ac",
      class: "candidate" }));
  }
  const d = front.map((p, j) => `${j ? "L" : "M"}${X(p.mass_kg).toFixed(1)},${Y(p.median_settling_s).toFixed(1)}`);
  svg.appendChild(svgEl("path", { d: d.join(""), fill: "none", stroke: "#4e79a7", "stroke-width": 1.5 }));
  front.forEach((p, i) => {
    const c = svgEl("circle", { cx: X(p.mass_kg), cy: Y(p.median_settling_s), r: 6, tabindex: 0, role: "button",
      class: "front-point" + (p.meets ? " meets" : ""), "data-index": i,
      fill: p.meets ? "#59a14f" : "#4e79a7", stroke: "#fff", "stroke-width": 1.5 });
    c.appendChild(svgEl("title", {}, `${p.mass_kg.toFixed(2)} kg, ${p.median_settling_s.toFixed(2)} s`
      + (p.meets ? ", meets the requirements" : "")));
    const pick = () => opts.onPick && opts.onPick(i);
    c.addEventListener("click", pick);
    c.addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); pick(); } });
    svg.appendChild(c);
  });
  return svg;
}

window.modsatCharts = { lineChart, niceTicks, tickLabels, designThumb, frontChart };
