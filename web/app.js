// The slamd page: wires the map, the plots, the status, the budget and tuning forms, and the map's
// set-pose and relocalise tools to the HTTP API and its event stream (docs/http-api.md).
//
// State the browser test reads is mirrored on <body> as data attributes: connected, tilesDrawn,
// tilesLoaded, trajectoryPoints, truthPoints, metricsPoints, budgetState, mapScale, localized
// (false while slamd relocalises), poseTool ('on' or 'off') and poseState ('dragging',
// 'cancelled', 'sending', 'sent', 'invalid', 'error').

import { ApiError, describeError, getJson, installTokenPrompt, mutate } from './api.js';
import { BudgetForm } from './budget.js';
import { clearFieldErrors, numberOf, setMessage, showFieldErrors } from './forms.js';
import { MapView } from './map-view.js';
import { LivePlots, plotsAvailable } from './plots.js';
import { TuningPanel } from './tuning.js';

const kStatusPeriodMs = 2000;
const kReopenDelayMs = 5000;  // when the browser gives up on the event stream (e.g. 503)
const kSyncRetryMs = 3000;

const $ = (id) => document.getElementById(id);
const body = document.body;

// ---- token prompt ----------------------------------------------------------------------------

let pendingToken = null;  // one prompt at a time, shared by concurrent requests

installTokenPrompt((reason) => {
  pendingToken ??= new Promise((resolve) => {
    const form = $('token-form');
    const input = $('token-input');
    const label = form.querySelector('label');
    label.textContent = `${reason} slamd needs an access token for this action:`.trim();
    form.hidden = false;
    input.value = '';
    input.focus();
    const finish = (token) => {
      form.hidden = true;
      form.removeEventListener('submit', onSubmit);
      $('token-cancel').removeEventListener('click', onCancel);
      pendingToken = null;
      resolve(token);
    };
    const onSubmit = (event) => {
      event.preventDefault();
      finish(input.value.trim() || null);
    };
    const onCancel = () => finish(null);
    form.addEventListener('submit', onSubmit);
    $('token-cancel').addEventListener('click', onCancel);
  });
  return pendingToken;
});

// ---- map -------------------------------------------------------------------------------------

const map = new MapView($('map-canvas'), {
  onCursor: (world) => {
    $('map-cursor').textContent = world
      ? `x ${world.x.toFixed(2)} m  y ${world.y.toFixed(2)} m` : '';
  },
  onViewChange: () => {
    $('map-follow').checked = map.follow;
  },
  onPoseDrag: (pose) => poseDragged(pose),
  onPoseDrawn: (pose) => poseDrawn(pose),
  onPoseCancelled: (why) => poseCancelled(why),
});
window.slamdPage = { map };  // for the browser test and the console
$('map-fit').addEventListener('click', () => map.fit());
$('map-follow').addEventListener('change', (event) => map.setFollow(event.target.checked));

let restartSeen = false;  // a `hello` from another slamd instance, not yet resynchronised

async function loadMap() {
  map.beginSync({ restarted: restartSeen });
  restartSeen = false;
  map.setIndex((await getJson('/api/v1/map')).body);
}

// Poses that arrive while a trajectory is being fetched may be missing from it: each fetch keeps
// them and appends them after replacing the trajectory (older ones are ignored by appendPose).
const poseBuffers = new Set();

async function loadTrajectory() {
  const buffer = [];
  poseBuffers.add(buffer);
  try {
    const { body: trajectory } = await getJson('/api/v1/trajectory');
    map.setTrajectory(trajectory.slam ?? [], trajectory.ground_truth ?? []);
    for (const pose of buffer) map.appendPose(pose);
  } finally {
    poseBuffers.delete(buffer);
  }
}

function onPose(pose) {
  // While slamd relocalises the pose is the last known one: the robot is drawn as stale.
  if (typeof pose.localized === 'boolean') showLocalized(pose.localized);
  map.appendPose(pose);
  for (const buffer of poseBuffers) buffer.push(pose);
}

// ---- plots -----------------------------------------------------------------------------------

let plots = null;
if (plotsAvailable()) {
  plots = new LivePlots({
    rays: $('plot-rays'),
    latency: $('plot-latency'),
    cpu: $('plot-cpu'),
    quality: $('plot-quality'),
    qualityCaption: $('quality-caption'),
  });
} else {
  $('plots-note').textContent = '(charts unavailable: /vendor/uplot/ is not served)';
}

/** What we know of the source: the ground truth and pose error exist only when simulated. */
function setSimulated(simulated) {
  $('legend-truth').hidden = !simulated;
  plots?.setSimulated(simulated);
}

// ---- status ----------------------------------------------------------------------------------

const number = (value) => (value == null ? '–' : Number(value).toLocaleString('en-US'));
const fixed = (value, digits, unit = '') =>
  (value == null ? '–' : `${value.toFixed(digits)}${unit}`);

function setBadge(element, state, good, bad, warn = []) {
  element.textContent = state ?? '–';
  const look = good.includes(state) ? 'badge-ok' : bad.includes(state) ? 'badge-bad'
    : warn.includes(state) ? 'badge-warn' : '';
  element.className = `badge ${look}`;
}

function setLinkState(state) {
  setBadge($('st-link'), state, ['running'], ['source_error', 'stopped', 'silent']);
}

function setSlamState(state) {
  // Relocalising: slamd searches the map for the robot and maps nothing meanwhile.
  setBadge($('st-slam'), state, ['running'], [], ['relocalizing']);
}

/** Whether slamd knows where the robot is (false while it relocalises). */
function showLocalized(localized) {
  map.setLocalized(localized);
  $('legend-stale').hidden = localized;
}

const kCauses = { resume: 'resume', request: 'request', hint: 'around a pose' };

/**
 * The relocalisation row: how many were taken, the last one's score, search time and cause, and
 * whether one is under way. `counts` is status.slam.relocalization (null from an event, which
 * carries only the state: the count stays as the last status said).
 */
function showRelocalization(state, counts) {
  const element = $('st-reloc');
  if (counts) element.dataset.count = String(counts.relocalizations ?? 0);
  const count = element.dataset.count;
  const last = state?.last;
  let text = count === undefined ? '–' : number(Number(count));
  if (last) {
    const cause = kCauses[last.cause] ?? last.cause;
    text += ` (last: score ${fixed(last.score, 2)} after ${fixed(last.search_s, 1, ' s')}, ${cause})`;
  }
  if (state?.active) text += ` — searching now (${kCauses[state.cause] ?? state.cause ?? '?'})`;
  element.textContent = text;
  const details = [];
  if (last) {
    details.push(`last: x ${fixed(last.x, 3)} m, y ${fixed(last.y, 3)} m, ` +
                 `heading ${fixed(last.theta * 180 / Math.PI, 1)}° at t ${fixed(last.t, 1)} s; ` +
                 `runner-up score ${fixed(last.runner_up_score, 2)}, ${number(last.points)} ` +
                 `points, ${number(last.searches)} searches, ${number(last.scans)} scans, ` +
                 `${number(last.lookups)} lookups`);
  }
  if (counts) {
    details.push(`poses set ${number(counts.poses_set)}, refused ${number(counts.refused)}, ` +
                 `unsure searches ${number(counts.unsure_searches)}, relocalising scans ` +
                 `${number(counts.scans)}`);
  }
  element.title = details.join('\n');
  if (state) {
    showLocalized(!state.active);
    showPlaces(state.active ? state.places ?? [] : []);
  }
  relocalizationSeen(state);
}

/** Where the robot may be while slamd is unsure: on the map and listed, each a hint to send. */
function showPlaces(places) {
  map.setPlaces(places);
  $('reloc-places').hidden = places.length === 0;
  $('legend-places').hidden = places.length === 0;
  $('reloc-places-list').replaceChildren(...places.map((place, i) => {
    const item = document.createElement('li');
    const heading = place.theta * 180 / Math.PI;
    item.append(`x ${fixed(place.x, 2)} m, y ${fixed(place.y, 2)} m, heading ` +
                `${fixed(heading, 0)}°, score ${fixed(place.score, 2)} `);
    const button = document.createElement('button');
    button.type = 'button';
    button.className = 'secondary small';
    button.dataset.place = String(i + 1);
    button.textContent = 'Search here';
    button.title = 'Let slamd search around this place (±0.3 m, ±15°)';
    button.addEventListener('click', () => sendPose({ x: place.x, y: place.y, theta_deg: heading },
                                                    true));
    item.append(button);
    return item;
  }));
}

/** The parameter set in use: a shipped one follows the budget, a given one holds. */
function showParams(params) {
  const element = $('st-params');
  element.textContent = params?.set ?? '–';
  element.title = params == null ? ''
    : params.follows_budget ? 'the shipped set of the budget (config/params/)'
      : 'a given set (--params or PATCH /api/v1/params), whatever the budget';
}

function showStatus(status) {
  const { source = {}, link = {}, slam = {} } = status;
  $('st-source').textContent = `${source.spec ?? '–'}${source.simulated ? ' (simulated)' : ''}`;
  $('st-source').title = source.description ?? '';
  $('source-label').textContent = source.spec ?? '';
  // A running link that hears nothing is shown as silent (the robot or its transport is quiet).
  setLinkState(link.silent ? 'silent' : link.state);
  $('st-frames').textContent = number(link.frames);
  $('st-drops').textContent = number(link.queue_drops);
  $('st-errors').textContent = number(link.source_errors);
  const linkError = $('st-link-error');
  linkError.hidden = !link.last_error;
  linkError.textContent = link.last_error ? `link: ${link.last_error}` : '';
  setSlamState(slam.state);
  if (slam.relocalization) showRelocalization(slam.relocalization.state, slam.relocalization);
  const relocalize = $('map-relocalize');
  relocalize.disabled = slam.tiles === 0;
  relocalize.title = relocalize.disabled ? 'Nothing is mapped yet: there is nothing to search'
    : 'Let slamd search the whole map for the robot';
  $('st-scans').textContent = number(slam.scans);
  $('st-late').textContent = number(slam.late_scans);
  $('st-particles').textContent = number(slam.particles);
  showParams(status.params);
  $('st-tiles').textContent = number(slam.tiles);
  $('st-latency').textContent = fixed(slam.last_latency_ms, 1, ' ms');
  $('st-realtime').textContent = fixed(slam.realtime_ratio, 1);
  $('st-time').textContent = fixed(slam.robot_time_s, 1, ' s');
  if (typeof source.simulated === 'boolean') setSimulated(source.simulated);
  if (status.features) showFeatures(status.features);
  if (status.job) tuning.show(status.job);
}

/** Buttons for what this slamd cannot do are disabled, and say why. */
function showFeatures(features) {
  const save = $('map-save');
  save.disabled = features.save === false;
  save.title = save.disabled ? 'slamd was started without --state-dir: there is nowhere to save'
    : 'Save the map and trajectory to the state directory';
  tuning.setAvailable(features.tuning !== false);
}

/** slamd is out of reach: what the status panel showed is no longer known. */
function forgetStatus() {
  setLinkState('unknown');
  setSlamState('unknown');
  $('st-link-error').hidden = true;
}

let statusInFlight = false;

async function loadStatus() {
  if (statusInFlight) return;
  statusInFlight = true;
  try {
    showStatus((await getJson('/api/v1/status')).body);
  } finally {
    statusInFlight = false;
  }
}

// ---- forms and map actions -------------------------------------------------------------------

const budget = new BudgetForm($('budget-form'));
const tuning = new TuningPanel($('tune-form'));

$('map-save').addEventListener('click', async () => {
  const message = $('map-message');
  setMessage(message, 'Saving…');
  try {
    const { body: saved } = await mutate('POST', '/api/v1/map/save', { body: {} });
    setMessage(message, `Saved ${number(saved.tiles)} tiles to ${saved.path}.`, 'ok');
  } catch (error) {
    setMessage(message, describeError(error), 'error');  // 409: slamd has no --state-dir
  }
});

$('map-reset').addEventListener('click', async () => {
  const message = $('map-message');
  if (!window.confirm('Reset SLAM? The map and the trajectory are cleared and SLAM restarts ' +
                      'from the origin.')) return;
  try {
    await mutate('POST', '/api/v1/reset', { body: {} });
    // At once, not at the `reset` event: no request goes out for a tile that is gone. The index
    // brings back any tile announced before this response arrived.
    map.clearTiles();
    loadMap().catch(() => {});
    setMessage(message, 'Reset.', 'ok');
  } catch (error) {
    setMessage(message, describeError(error), 'error');
  }
});

// ---- set pose and relocalise -----------------------------------------------------------------

const poseForm = $('pose-form');
const poseMessage = $('pose-message');
const kDeg = 180 / Math.PI;
// "search around": slamd relocalises within three deviations, ±0.3 m and ±15°.
const kAround = { sigma_m: 0.1, sigma_deg: 5 };
let poseSending = false;
let watchedSearch = null;  // {since: the last record's t before we asked}: a search we asked for

function setPoseState(state) {
  body.dataset.poseState = state;
}

function setPoseTool(on) {
  map.setTool(on ? 'pose' : null);
  $('pose-tool').setAttribute('aria-pressed', String(on));
  poseForm.hidden = !on;
  body.dataset.poseTool = on ? 'on' : 'off';
  if (!on) clearFieldErrors(poseForm);
}

function fillPoseFields(pose) {
  poseForm.elements.namedItem('x').value = pose.x.toFixed(3);
  poseForm.elements.namedItem('y').value = pose.y.toFixed(3);
  poseForm.elements.namedItem('theta_deg').value = (pose.theta * kDeg).toFixed(1);
}

function poseDragged(pose) {
  if (!pose) return;
  clearFieldErrors(poseForm);
  fillPoseFields(pose);
  setPoseState('dragging');
}

function poseDrawn(pose) {
  fillPoseFields(pose);
  // The drag's own numbers, not the fields' rounded ones.
  sendPose({ x: pose.x, y: pose.y, theta_deg: pose.theta * kDeg });
}

function poseCancelled(why) {
  setPoseState('cancelled');
  if (why === 'escape') setMessage(poseMessage, 'Set pose cancelled.');
  if (why === 'short') {
    setMessage(poseMessage, 'Drag from the robot\'s position towards where it faces: a press ' +
                            'alone gives no heading.', 'error');
  }
}

/**
 * POST /api/v1/pose with `{x, y, theta_deg}` and the sigmas of the mode chosen (`around`: a
 * hint whatever the mode).
 */
async function sendPose(pose, around = poseForm.elements.namedItem('mode').value === 'around') {
  if (poseSending) return;
  clearFieldErrors(poseForm);
  const request = around ? { ...pose, ...kAround } : { ...pose };
  poseSending = true;
  setPoseState('sending');
  setMessage(poseMessage, 'Setting the pose…');
  map.showPendingPose({ x: pose.x, y: pose.y, theta: pose.theta_deg / kDeg });
  const where = `x ${pose.x.toFixed(2)} m, y ${pose.y.toFixed(2)} m, ` +
                `heading ${pose.theta_deg.toFixed(0)}°`;
  try {
    const before = lastRelocalization;
    const { body: answer } = await mutate('POST', '/api/v1/pose', { body: request });
    if (answer?.mode === 'relocalize_around') {
      watchedSearch = { since: before?.t ?? null };
      setMessage(poseMessage, `Searching around ${where} (±0.3 m, ±15°)…`, 'ok');
    } else {
      setMessage(poseMessage, `Pose set: ${where}.`, 'ok');
    }
    setPoseState('sent');
    setPoseTool(false);  // one pose per use, as a tool of a map viewer
    // The dashed arrow stays until the scan that takes the pose is drawn.
    setTimeout(() => map.showPendingPose(null), 1200);
    loadStatus().catch(() => {});
  } catch (error) {
    map.showPendingPose(null);
    if (error instanceof ApiError && error.status === 422) {
      const unplaced = showFieldErrors(poseForm, error.errors);
      setMessage(poseMessage, unplaced.length > 0 ? `Not set: ${unplaced.join('; ')}`
        : 'Not set: see the highlighted field.', 'error');
      setPoseState('invalid');
    } else {
      setMessage(poseMessage, describeError(error), 'error');
      setPoseState('error');
    }
  } finally {
    poseSending = false;
  }
}

/** The pose typed in the form. */
function submitTypedPose() {
  clearFieldErrors(poseForm);
  const pose = {};
  const problems = [];
  for (const key of ['x', 'y', 'theta_deg']) {
    const value = numberOf(poseForm.elements.namedItem(key));
    if (value === null) problems.push({ pointer: `/${key}`, detail: 'a number is required' });
    else pose[key] = value;
  }
  if (problems.length > 0) {
    showFieldErrors(poseForm, problems);
    setMessage(poseMessage, 'Please correct the highlighted field.', 'error');
    setPoseState('invalid');
    return;
  }
  sendPose(pose);
}

let lastRelocalization = null;  // the last record slamd told of (status or event)

/** Tells how a search the page asked for ended, once slamd reports it. */
function relocalizationSeen(state) {
  if (!state) return;
  const last = state.last ?? null;
  if (watchedSearch && !state.active && last && last.t !== watchedSearch.since) {
    setMessage(poseMessage, `Relocalised: x ${fixed(last.x, 2)} m, y ${fixed(last.y, 2)} m, ` +
               `score ${fixed(last.score, 2)} after ${fixed(last.search_s, 1, ' s')}.`, 'ok');
    watchedSearch = null;
  }
  lastRelocalization = last;
}

$('pose-tool').addEventListener('click', () => {
  const on = body.dataset.poseTool !== 'on';
  setPoseTool(on);
  setMessage(poseMessage, '');
});
poseForm.addEventListener('submit', (event) => {
  event.preventDefault();
  submitTypedPose();
});
poseForm.addEventListener('input', (event) => {
  clearFieldErrors(poseForm, `/${event.target.name}`);
  if (event.target.name === 'mode') clearFieldErrors(poseForm);
});
window.addEventListener('keydown', (event) => {
  if (event.key !== 'Escape' || body.dataset.poseTool !== 'on') return;
  // Esc cancels a drag under way, else puts the tool away.
  if (!map.cancelPoseDrag('escape')) {
    setPoseTool(false);
    setMessage(poseMessage, '');
  }
});
body.dataset.poseTool = 'off';

$('map-relocalize').addEventListener('click', async () => {
  setMessage(poseMessage, 'Asking slamd to relocalise…');
  const before = lastRelocalization;
  try {
    await mutate('POST', '/api/v1/relocalize', { body: {} });
    watchedSearch = { since: before?.t ?? null };
    setMessage(poseMessage, 'Relocalising: slamd searches the whole map for the robot…', 'ok');
    loadStatus().catch(() => {});
  } catch (error) {
    if (error instanceof ApiError && error.status === 409) {
      setMessage(poseMessage, 'Nothing to relocalise in: slamd has mapped nothing yet.', 'error');
    } else {
      setMessage(poseMessage, describeError(error), 'error');
    }
  }
});

// ---- event stream ----------------------------------------------------------------------------

let needsSync = false;  // set when the stream dropped: the next `hello` refetches everything
let instance = null;  // of the slamd whose `hello` came last (changes with every start)

function setConnected(state) {
  const badge = $('connection');
  badge.textContent = state;
  const look = { connected: 'badge-ok', snapshot: '' }[state] ?? 'badge-bad';
  badge.className = `badge ${look}`;
  body.dataset.connected = String(state === 'connected');
}

/** Everything the event stream may have missed: map index, trajectory, budget, job, status. */
async function sync() {
  const results = await Promise.allSettled([
    loadMap(), loadTrajectory(), budget.load({ keepEdits: true }), tuning.load(), loadStatus(),
  ]);
  if (results.some((r) => r.status === 'rejected')) {
    // Try again while the stream is up; if it is down, its next `hello` syncs.
    setTimeout(() => {
      if (body.dataset.connected === 'true') sync();
      else needsSync = true;
    }, kSyncRetryMs);
  }
}

function parse(handler) {
  return (event) => handler(JSON.parse(event.data));
}

function connect() {
  const events = new EventSource('/api/v1/events');
  events.addEventListener('hello', parse((hello) => {
    setConnected('connected');
    if (typeof hello.simulated === 'boolean') setSimulated(hello.simulated);
    if (instance !== null && hello.instance !== instance) {
      restartSeen = true;
      needsSync = true;
    }
    instance = hello.instance ?? null;
    if (needsSync) {
      needsSync = false;
      sync();
    }
  }));
  events.addEventListener('tiles', parse((data) => map.announceTiles(data.tiles ?? [])));
  events.addEventListener('pose', parse(onPose));
  events.addEventListener('metrics', parse((metrics) => plots?.push(metrics)));
  events.addEventListener('budget', parse((data) => budget.applyRemote(data)));
  // The set in use changed (a budget change, a patch): its name is in the event.
  events.addEventListener('params', parse((data) => {
    $('st-params').textContent = data.set ?? '–';
    loadStatus().catch(() => {});
  }));
  events.addEventListener('job', parse((job) => tuning.show(job)));
  // A relocalisation started or ended: its state is in the event, the counts in the status.
  events.addEventListener('relocalization', parse((state) => {
    showRelocalization(state, null);
    loadStatus().catch(() => {});
  }));
  events.addEventListener('status', parse((states) => {
    setLinkState(states.link);
    setSlamState(states.slam);
    loadStatus().catch(() => {});
  }));
  events.addEventListener('reset', () => {
    map.clearTiles();  // the tiles follow in `tiles` events
    map.clearTrajectory();
    plots?.clear();
    loadTrajectory().catch(() => {});
  });
  events.addEventListener('error', () => {
    setConnected('disconnected');
    forgetStatus();
    needsSync = true;
    map.suspend();
    if (events.readyState === EventSource.CLOSED) {
      // The browser gave up (e.g. 503 too many streams): open a new stream a little later.
      setTimeout(connect, kReopenDelayMs);
    }
  });
}

// ---- start -----------------------------------------------------------------------------------

// `?static`: one synchronisation and no event stream, so that the page settles (a headless
// `chromium --screenshot` of it finishes; the stream would keep it loading for ever).
if (new URLSearchParams(window.location.search).has('static')) {
  setConnected('snapshot');
  sync();
} else {
  setConnected('connecting…');
  connect();
  sync();
  setInterval(() => {
    if (!document.hidden && !needsSync) loadStatus().catch(() => {});
  }, kStatusPeriodMs);
}
