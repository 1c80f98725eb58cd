// The job page's two live charts, drawn with uPlot (vendored, see vendor/uplot/README.md) from
// GET /jobs/{id}/convergence:
//  - estimated relative error against elapsed time, both axes logarithmic, with the 1/√t slope
//    of an unbiased Monte Carlo estimator through the first point for reference;
//  - samples per second against elapsed time.
// Each chart's container carries `data-points`, the number of points plotted, for tests and
// for anyone scripting the page. `update(points, tag)` redraws when the points or the tag (what
// they are the history of: a frame job's frame) change.

import uPlot from './vendor/uplot/uPlot.esm.js';
import { el, fmtError, fmtSi, fmtDuration } from './util.js';

const HEIGHT = 240;

function widthOf(node) {
  return Math.max(280, Math.floor(node.clientWidth || 0));
}

// A chart in `container` that follows its width.
function makePlot(container, opts) {
  const plotBox = el('div', { class: 'plot' });
  container.append(plotBox);
  const plot = new uPlot({ ...opts, width: widthOf(plotBox), height: HEIGHT }, opts.data, plotBox);
  const ro = new ResizeObserver(() => plot.setSize({ width: widthOf(plotBox), height: HEIGHT }));
  ro.observe(plotBox);
  return {
    plot,
    destroy() {
      ro.disconnect();
      plot.destroy();
    },
  };
}

const AXIS = { stroke: 'currentColor', grid: { stroke: 'rgba(127,127,127,0.25)' }, ticks: { stroke: 'rgba(127,127,127,0.4)' } };

export function errorChart(container, summary) {
  const { plot, destroy } = makePlot(container, {
    data: [[], [], []],
    scales: { x: { time: false, distr: 3 }, y: { distr: 3 } },
    axes: [
      { ...AXIS, label: 'elapsed (s)' },
      { ...AXIS, label: 'relative error', size: 70, values: (u, splits) => splits.map((v) => (v == null ? '' : fmtError(v))) },
    ],
    series: [
      { label: 'elapsed', value: (u, v) => (v == null ? '–' : `${v.toPrecision(3)} s`) },
      { label: 'relative error', stroke: '#2563eb', width: 2, points: { show: true, size: 5 }, value: (u, v) => fmtError(v) },
      { label: '1/√t', stroke: '#9ca3af', width: 1.5, dash: [6, 4], points: { show: false }, value: (u, v) => fmtError(v) },
    ],
  });
  let last = '';
  return {
    destroy,
    update(points, tag = '') {
      // Log axes take positive values only: t = 0 and "no estimate yet" are left out.
      const pts = points.filter((p) => p.elapsed_s > 0 && p.relative_error > 0);
      const key = `${tag}:${pts.length}:${pts.length ? pts[pts.length - 1].elapsed_s : ''}`;
      if (key === last) return;
      last = key;
      const xs = pts.map((p) => p.elapsed_s);
      const ys = pts.map((p) => p.relative_error);
      // Error ∝ 1/√(samples) ∝ 1/√t at a steady rate: the line an unbiased estimator follows.
      const ref = pts.length ? xs.map((t) => ys[0] * Math.sqrt(xs[0] / t)) : [];
      plot.setData([xs, ys, ref]);
      container.dataset.points = String(pts.length);
      summary.textContent = pts.length
        ? `${pts.length} points; latest ${fmtError(ys[ys.length - 1])} after ${fmtDuration(xs[xs.length - 1])}.`
        : 'No error estimate yet (it needs samples in every pixel).';
    },
  };
}

export function rateChart(container, summary) {
  const { plot, destroy } = makePlot(container, {
    data: [[], []],
    scales: { x: { time: false } },
    axes: [
      { ...AXIS, label: 'elapsed (s)' },
      { ...AXIS, label: 'samples / s', size: 70, values: (u, splits) => splits.map((v) => (v == null ? '' : fmtSi(v))) },
    ],
    series: [
      { label: 'elapsed', value: (u, v) => (v == null ? '–' : `${v.toPrecision(3)} s`) },
      { label: 'samples/s', stroke: '#16a34a', fill: 'rgba(22,163,74,0.12)', width: 2, points: { show: true, size: 5 }, value: (u, v) => (v == null ? '–' : fmtSi(v)) },
    ],
  });
  let last = '';
  return {
    destroy,
    update(points, tag = '') {
      const key = `${tag}:${points.length}:${points.length ? points[points.length - 1].elapsed_s : ''}`;
      if (key === last) return;
      last = key;
      plot.setData([points.map((p) => p.elapsed_s), points.map((p) => p.samples_per_second)]);
      container.dataset.points = String(points.length);
      const lastRate = points.length ? points[points.length - 1].samples_per_second : 0;
      summary.textContent = points.length
        ? `${points.length} points; latest ${fmtSi(lastRate)} samples/s.`
        : 'No samples merged yet.';
    },
  };
}
