// Live plots of the `metrics` events and the tuning job's fitness per generation, with uPlot
// (loaded by index.html as a classic script: window.uPlot). Without uPlot the page still works.

const kMaxPoints = 300;
const kHeight = 150;
const kColours = ['#1565c0', '#2e7d32', '#c62828', '#6a1b9a'];
// Tick steps for scan and generation numbers: whole numbers only.
const kWholeSteps = [1, 2, 5, 10, 20, 25, 50, 100, 200, 250, 500, 1e3, 2e3, 5e3, 1e4, 2e4, 5e4, 1e5,
                     2e5, 5e5, 1e6];

export const plotsAvailable = () => typeof window.uPlot === 'function';

/** uPlot options shared by every plot: x is the scan number, not time. */
function baseOptions(width, series, yLabel) {
  return {
    width,
    height: kHeight,
    scales: { x: { time: false } },
    legend: { live: true },
    cursor: { drag: { x: false, y: false } },
    axes: [
      { stroke: '#555', grid: { stroke: '#eee' }, ticks: { stroke: '#ccc' }, incrs: kWholeSteps },
      { stroke: '#555', grid: { stroke: '#eee' }, ticks: { stroke: '#ccc' }, label: yLabel,
        size: 56, labelSize: 16 },
    ],
    series: [{ label: 'scan' }, ...series],
  };
}

function widthOf(element) {
  return Math.max(200, Math.floor(element.clientWidth));
}

/** Keeps a uPlot as wide as its container. */
function fitToContainer(plot, element) {
  new ResizeObserver(() => {
    const width = widthOf(element);
    if (width !== plot.width) plot.setSize({ width, height: kHeight });
  }).observe(element);
}

/** A rolling plot of the last kMaxPoints values of a few `metrics` keys. */
class RollingPlot {
  constructor(element, yLabel, series) {
    this.keys = series.map((s) => s.key);
    this.transforms = series.map((s) => s.transform ?? ((v) => v));
    this.columns = [[], ...series.map(() => [])];
    const uSeries = series.map((s, i) => ({
      label: s.label,
      stroke: s.colour ?? kColours[i],
      width: 1.5,
      dash: s.dash,
      value: (u, v) => (v == null ? '–' : s.format ? s.format(v) : v.toLocaleString()),
    }));
    this.plot = new window.uPlot(baseOptions(widthOf(element), uSeries, yLabel), this.columns,
                                 element);
    fitToContainer(this.plot, element);
  }

  push(metrics) {
    const scan = metrics.scan;
    const xs = this.columns[0];
    if (xs.length > 0 && scan <= xs.at(-1)) {
      // Scan numbers went back (a reset or a restarted slamd): start again.
      this.clear();
    }
    xs.push(scan);
    this.keys.forEach((key, i) => {
      const value = metrics[key];
      this.columns[i + 1].push(value == null ? null : this.transforms[i](value));
    });
    if (xs.length > kMaxPoints) for (const column of this.columns) column.shift();
  }

  clear() {
    for (const column of this.columns) column.length = 0;
    this.redraw();
  }

  redraw() {
    this.plot.setData(this.columns);
  }
}

/** The four live plots; `simulated` picks pose error (m) or ESS as the quality measure. */
export class LivePlots {
  constructor(elements) {
    this.elements = elements;
    this.plots = {};
    this.simulated = null;
    this.redrawQueued = false;
    this.count = 0;
    this.plots.rays = new RollingPlot(elements.rays, 'rays', [
      { key: 'rays_planned', label: 'planned' },
      { key: 'rays_used', label: 'used' },
      { key: 'quota', label: 'quota', colour: '#c62828', dash: [6, 4] },
    ]);
    this.plots.latency = new RollingPlot(elements.latency, 'ms', [
      { key: 'latency_ms', label: 'latency', format: (v) => v.toFixed(2) },
    ]);
    this.plots.cpu = new RollingPlot(elements.cpu, '%', [
      { key: 'cpu_share', label: 'CPU share', transform: (v) => 100 * v,
        format: (v) => `${v.toFixed(1)} %` },
    ]);
  }

  /** Creates (or recreates) the quality plot once we know whether the source is simulated. */
  setSimulated(simulated) {
    if (this.simulated === simulated) return;
    this.simulated = simulated;
    this.plots.quality?.plot.destroy();
    this.elements.quality.replaceChildren();
    this.elements.qualityCaption.textContent = simulated
      ? 'Error vs ground truth (m), aligned over the run so far as the ATE is'
      : 'Effective sample size';
    this.plots.quality = simulated
      ? new RollingPlot(this.elements.quality, 'm', [
        { key: 'ate_m', label: 'ATE so far', format: (v) => v.toFixed(3) },
        { key: 'pose_error_m', label: 'pose error', colour: '#ef6c00',
          format: (v) => v.toFixed(3) }])
      : new RollingPlot(this.elements.quality, 'ESS', [
        { key: 'ess', label: 'ESS', format: (v) => v.toFixed(1) }]);
  }

  push(metrics) {
    for (const plot of Object.values(this.plots)) plot.push(metrics);
    this.count += 1;
    document.body.dataset.metricsPoints = String(this.count);
    if (!this.redrawQueued) {
      this.redrawQueued = true;
      requestAnimationFrame(() => {
        this.redrawQueued = false;
        for (const plot of Object.values(this.plots)) plot.redraw();
      });
    }
  }

  clear() {
    for (const plot of Object.values(this.plots)) plot.clear();
  }
}

/** Fitness per generation of a tuning job, like the paper's Fig. 10: median, q1–q3 band, min. */
export class TuningPlot {
  constructor(element) {
    const band = 'rgba(21, 101, 192, 0.18)';
    const fmt = (u, v) => (v == null ? '–' : v.toFixed(3));
    const options = baseOptions(widthOf(element), [
      { label: 'q3', stroke: band, width: 1, value: fmt },
      { label: 'q1', stroke: band, width: 1, value: fmt },
      { label: 'median', stroke: '#1565c0', width: 2, value: fmt },
      { label: 'min', stroke: '#2e7d32', width: 1.5, dash: [5, 4], value: fmt },
    ], 'fitness E');
    options.axes[0].label = 'generation';
    options.axes[0].labelSize = 16;
    options.series[0].label = 'generation';
    options.bands = [{ series: [1, 2], fill: band }];  // fill between q3 and q1
    this.plot = new window.uPlot(options, [[], [], [], [], []], element);
    fitToContainer(this.plot, element);
  }

  /** Shows a job's `history` ([{generation, min, q1, median, q3, max}]). */
  show(history) {
    const rows = history ?? [];
    this.plot.setData([
      rows.map((h) => h.generation),
      rows.map((h) => h.q3),
      rows.map((h) => h.q1),
      rows.map((h) => h.median),
      rows.map((h) => h.min),
    ]);
  }
}
