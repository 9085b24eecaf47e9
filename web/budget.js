// The ray budget form: GET /api/v1/budget, PATCH it as a merge patch guarded by If-Match, and
// follow the `budget` events that other clients cause.

import { ApiError, describeError, getJson, mutate } from './api.js';
import { clearFieldErrors, numberOf, setMessage, showFieldErrors } from './forms.js';

const kUrl = '/api/v1/budget';
const kKeys = ['mode', 'rays_per_scan', 'cpu_share', 'policy', 'max_particles'];

export class BudgetForm {
  constructor(form) {
    this.form = form;
    this.message = form.querySelector('#budget-message');
    this.current = null;      // the budget as slamd last told us
    this.etag = null;         // its ETag, sent back as If-Match
    this.dirty = new Set();   // keys the user edited since
    this.submitting = false;

    form.addEventListener('input', (event) => this.edited(event.target));
    form.addEventListener('change', (event) => this.edited(event.target));
    form.addEventListener('submit', (event) => {
      event.preventDefault();
      this.submit();
    });
    form.querySelector('#budget-revert').addEventListener('click', () => {
      this.dirty.clear();
      clearFieldErrors(form);
      this.fill(this.current);
      setMessage(this.message, '');
    });
  }

  field(key) {
    return this.form.elements.namedItem(key);
  }

  edited(element) {
    if (!kKeys.includes(element.name)) return;
    this.dirty.add(element.name);
    clearFieldErrors(this.form, `/${element.name}`);
    if (element.name === 'mode') this.showModeFields();
    this.setState('editing');
  }

  /** Shows the rays or the CPU share field, whichever the selected mode uses. */
  showModeFields() {
    const mode = this.field('mode').value;
    for (const element of this.form.querySelectorAll('[data-mode]')) {
      element.hidden = element.dataset.mode !== mode;
    }
  }

  /** Puts budget values into the fields the user is not editing. */
  fill(budget, { keepEdits = false } = {}) {
    if (!budget) return;
    for (const key of kKeys) {
      if (keepEdits && this.dirty.has(key)) continue;
      if (budget[key] !== undefined) this.field(key).value = String(budget[key]);
    }
    this.showModeFields();
  }

  setState(state) {
    document.body.dataset.budgetState = state;
  }

  /** Loads the budget and its ETag (at start, after a reconnect, after a 412). */
  async load({ keepEdits = false } = {}) {
    const { body, etag } = await getJson(kUrl);
    this.current = body;
    this.etag = etag;
    if (!keepEdits) this.dirty.clear();
    this.fill(body, { keepEdits });
  }

  /** A `budget` event: another client (or our own PATCH) changed it. */
  async applyRemote(budget) {
    const changed = this.current !== null &&
                    kKeys.some((key) => this.current[key] !== budget[key]);
    this.current = budget;
    this.fill(budget, { keepEdits: true });
    if (!changed || this.submitting) return;
    setMessage(this.message, this.dirty.size > 0
      ? 'Changed by another client; your edits are kept.' : 'Changed by another client.');
    try {
      await this.load({ keepEdits: true });  // for the new ETag
    } catch {
      // The next submit gets 412 and reloads.
    }
  }

  /** The merge patch: the keys whose field differs from the current budget. */
  patch() {
    const patch = {};
    const problems = [];
    for (const key of kKeys) {
      const input = this.field(key);
      if (input.closest('.field')?.hidden) continue;
      let value = input.value;
      if (input.type === 'number') {
        value = numberOf(input);
        if (value === null) {
          problems.push({ pointer: `/${key}`, detail: 'a number is required' });
          continue;
        }
      }
      if (value !== this.current?.[key]) patch[key] = value;
    }
    return { patch, problems };
  }

  async submit() {
    clearFieldErrors(this.form);
    const { patch, problems } = this.patch();
    if (problems.length > 0) {
      showFieldErrors(this.form, problems);
      setMessage(this.message, 'Please correct the highlighted field.', 'error');
      this.setState('invalid');
      return;
    }
    if (Object.keys(patch).length === 0) {
      setMessage(this.message, 'Nothing to change.');
      this.setState('applied');
      return;
    }
    this.submitting = true;
    setMessage(this.message, 'Applying…');
    try {
      const { body, etag } = await mutate('PATCH', kUrl, {
        body: patch,
        contentType: 'application/merge-patch+json',
        ifMatch: this.etag ?? undefined,
      });
      this.current = body;
      this.etag = etag;
      this.dirty.clear();
      this.fill(body);
      if (!etag) await this.load();
      setMessage(this.message, 'Applied; takes effect from the next scan.', 'ok');
      this.setState('applied');
    } catch (error) {
      this.failed(error);
    } finally {
      this.submitting = false;
    }
  }

  async failed(error) {
    if (error instanceof ApiError && error.status === 422) {
      const unplaced = showFieldErrors(this.form, error.errors);
      setMessage(this.message, unplaced.length > 0 ? unplaced.join('; ')
        : 'Not applied: see the highlighted field.', 'error');
      this.setState('invalid');
    } else if (error instanceof ApiError && error.status === 412) {
      this.setState('conflict');
      try {
        await this.load();
        setMessage(this.message, 'Someone else changed the budget meanwhile: the form now shows ' +
                                 'the current values. Edit and apply again.', 'error');
      } catch (reloadError) {
        setMessage(this.message, describeError(reloadError), 'error');
      }
    } else {
      setMessage(this.message, describeError(error), 'error');
      this.setState('error');
    }
  }
}
