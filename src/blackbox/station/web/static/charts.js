// Charts of the entity page: the last minutes of each characteristic, drawn with uPlot
// (vendored), extended in place by station.js as values arrive.
"use strict";
(function () {
  const holder = document.getElementById("series");
  const data = JSON.parse(holder.dataset.series || "{}");
  // A moment's page (moment.html) shades the span that was clicked on the timeline.
  const from = Number(holder.dataset.from), to = Number(holder.dataset.to);
  const shade = isFinite(from) && isFinite(to) && holder.dataset.from ? [function (u) {
    const left = u.valToPos(from, "x", true), right = u.valToPos(to, "x", true);
    u.ctx.save();
    u.ctx.fillStyle = "rgba(207, 34, 46, 0.10)";
    u.ctx.fillRect(left, u.bbox.top, Math.max(right - left, 1), u.bbox.height);
    u.ctx.restore();
  }] : [];
  const charts = {};
  const windowSeconds = 300;
  document.querySelectorAll("figure.chart").forEach(function (fig) {
    const id = fig.dataset.char;
    const series = data[id] || [[], []];
    const limits = (fig.dataset.thresholds || "").split(" ").filter(Boolean).map(Number);
    const cols = [series[0].slice(), series[1].slice()];
    limits.forEach(function (t) { cols.push(cols[0].map(function () { return t; })); });
    const opts = {
      width: Math.min(560, fig.clientWidth || 560), height: 180,
      series: [{}, { label: fig.dataset.label, stroke: "#1f6feb", width: 1.5 }].concat(
        limits.map(function (t) { return { label: "threshold " + t, stroke: "#d29922", dash: [6, 4], width: 1 }; })),
      axes: [{}, { label: fig.dataset.unit || "" }],
      legend: { show: true },
      hooks: { drawClear: shade },
    };
    charts[id] = { plot: new uPlot(opts, cols, fig), cols: cols, limits: limits };
  });
  window.stationCharts = {
    add: function (id, t, v) {
      const c = charts[id];
      if (!c) return;
      const xs = c.cols[0];
      if (xs.length && t <= xs[xs.length - 1]) return;
      xs.push(t); c.cols[1].push(v);
      c.limits.forEach(function (lim, i) { c.cols[2 + i].push(lim); });
      while (xs.length && xs[0] < t - windowSeconds) c.cols.forEach(function (col) { col.shift(); });
      c.plot.setData(c.cols);
    },
  };
})();
