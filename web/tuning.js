// The tuning panel: start a parameter tuning job (POST /api/v1/jobs/tune), follow it through
// `job` events, cancel or forget it (DELETE /api/v1/jobs/{id}), plot its fitness history.

import { ApiError, describeError, getJson, mutate } from './api.js';
import { clearFieldErrors, numberOf, setMessage, showFieldErrors } from './forms.js';
import { TuningPlot, plotsAvailable } from './plots.js';

const $ = (id) => document.getElementById(id);

export class TuningPanel {
  constructor(form) {
    this.form = form;
    this.message = $('tune-message');
    this.cancelButton = $('tune-cancel');
    this.job = null;
    this.plot = null;
    this.available = true;  // slamd has experiments to tune on (status.features.tuning)

    form.addEventListener('submit', (event) => {
      event.preventDefault();
      this.start();
    });
    form.addEventListener('input', (event) => clearFieldErrors(form, `/${event.target.name}`));
    this.cancelButton.addEventListener('click', () => this.cancelOrForget());
  }

  /** Whether slamd can tune at all (it was started with --experiments): Start follows. */
  setAvailable(available) {
    this.available = available;
    this.updateStart();
  }

  updateStart() {
    const start = $('tune-start');
    start.disabled = !this.available || this.job?.state === 'running';
    start.title = this.available ? ''
      : 'slamd was started without --experiments: there is nothing to tune on';
  }

  /** Shows the newest job slamd knows of, if any. */
  async load() {
    const { body } = await getJson('/api/v1/jobs');
    const jobs = body.jobs ?? [];
    const newest = jobs.reduce((a, b) => (a && Number(a.id) > Number(b.id) ? a : b), null);
    this.show(newest);
  }

  /** The request body: only the fields the user filled in (slamd has defaults for the rest). */
  body() {
    const body = {};
    const problems = [];
    for (const key of ['budget', 'population', 'generations']) {
      const input = this.form.elements.namedItem(key);
      if (input.value.trim() === '') continue;
      const value = numberOf(input);
      if (value === null) problems.push({ pointer: `/${key}`, detail: 'a number is required' });
      else body[key] = value;
    }
    body.policy = this.form.elements.namedItem('policy').value;
    return { body, problems };
  }

  async start() {
    clearFieldErrors(this.form);
    const { body, problems } = this.body();
    if (problems.length > 0) {
      showFieldErrors(this.form, problems);
      setMessage(this.message, 'Please correct the highlighted field.', 'error');
      return;
    }
    setMessage(this.message, 'Starting…');
    try {
      const { body: job } = await mutate('POST', '/api/v1/jobs/tune', { body });
      setMessage(this.message, `Job ${job.id} started.`, 'ok');
      this.show(job);
    } catch (error) {
      if (error instanceof ApiError && error.status === 422) {
        const unplaced = showFieldErrors(this.form, error.errors);
        setMessage(this.message, unplaced.length > 0 ? unplaced.join('; ')
          : 'Not started: see the highlighted field.', 'error');
      } else {
        // 409: a job is already running, or slamd has no experiments to tune on.
        setMessage(this.message, describeError(error), 'error');
      }
    }
  }

  async cancelOrForget() {
    if (!this.job) return;
    const running = this.job.state === 'running';
    try {
      const { body } = await mutate('DELETE', `/api/v1/jobs/${encodeURIComponent(this.job.id)}`);
      if (running) {
        setMessage(this.message, 'Cancelling…');
        if (body && body.id) this.show(body);
      } else {
        setMessage(this.message, '');
        this.show(null);
      }
    } catch (error) {
      if (error instanceof ApiError && error.status === 404) this.show(null);
      setMessage(this.message, describeError(error), 'error');
    }
  }

  /** Shows a job object (from a response, a `job` event or the status); null hides it. */
  show(job) {
    // Events of an older job must not replace a newer one.
    if (job && this.job && Number(job.id) < Number(this.job.id)) return;
    this.job = job;
    $('tune-job').hidden = !job;
    this.cancelButton.disabled = !job;
    this.cancelButton.textContent = job && job.state !== 'running' ? 'Forget' : 'Cancel';
    this.updateStart();
    if (!job) return;

    $('job-id').textContent = job.id;
    const state = $('job-state');
    state.textContent = job.state;
    const look = { running: 'badge-busy', done: 'badge-ok', failed: 'badge-bad' }[job.state];
    state.className = `badge ${look ?? ''}`;
    const progress = $('job-progress');
    progress.value = Math.min(1, Math.max(0, job.progress ?? 0));
    $('job-progress-text').textContent =
      `generation ${job.generation ?? 0}/${job.generations ?? '?'} · ` +
      `evaluations ${job.evaluations_done ?? 0}/${job.evaluations_total ?? '?'} · ` +
      `${Math.round(100 * (job.progress ?? 0))} % · budget ${job.budget}, ${job.policy}`;
    $('job-best').textContent = job.best
      ? `best fitness ${Number(job.best.fitness).toFixed(4)}` : '';
    const error = $('job-error');
    error.hidden = !job.error;
    error.textContent = job.error ?? '';
    $('job-params').hidden = !job.best?.params;
    $('job-params-json').textContent = job.best?.params
      ? JSON.stringify(job.best.params, null, 2) : '';

    if (plotsAvailable()) {
      this.plot ??= new TuningPlot($('plot-tuning'));
      this.plot.show(job.history);
    }
  }
}
