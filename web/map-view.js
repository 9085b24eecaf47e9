// The map canvas: occupancy tiles from slamd, the SLAM trajectory, the ground truth and the robot,
// with pan (drag), zoom (wheel, around the cursor) and fit, and the "set pose" tool: with it
// active, a drag from the robot's position towards its heading draws an arrow and hands the pose
// it means to the page (hooks.onPoseDrawn); the view holds still meanwhile (no auto-fit, no
// follow), so that the point under the pointer stays the one pressed.
//
// Coordinates: the view keeps a world centre (metres) and a scale in CSS pixels per metre; the
// canvas backing store is sized at device pixel ratio and everything is drawn in device pixels.
// World y grows upwards, screen y downwards. toWorld() and toScreen() convert between the map
// frame and CSS pixels relative to the canvas; the pose tool uses toWorld() and nothing else.

const kMaxConcurrentFetches = 4;  // the browser allows 6 per host; the event stream holds one
const kRetryDelayMs = 3000;       // doubled after each failure of the same tile
const kMaxRetries = 3;
const kMinScale = 2;              // CSS px per metre
const kMaxScale = 4000;
const kRobotRadiusM = 0.085;      // the marXbot is 17 cm across
const kMinPoseDragPx = 8;         // a shorter drag says no heading: the pose tool ignores it
const kColours = {
  background: 'rgb(205, 205, 205)',  // "unknown" of the map_server trinary grey levels
  slam: '#1565c0',
  truth: 'rgba(245, 124, 0, 0.6)',
  truthRobot: '#ef6c00',
  robot: '#1565c0',
  stale: '#757575',              // the robot's last known pose while slamd relocalises
  pose: '#8e24aa',               // the pose tool's arrow
  place: '#2e7d32',              // where the robot may be while slamd is unsure
  scale: '#222',
};

/** Parses an ETag such as `"1234"` or `W/"1234"` into a number (NaN if it is not one). */
function etagVersion(etag) {
  const match = /(\d+)/.exec(etag ?? '');
  return match ? Number(match[1]) : NaN;
}

/** A "nice" length (1, 2 or 5 times a power of ten) close to `length`. */
function niceLength(length) {
  const power = 10 ** Math.floor(Math.log10(length));
  for (const step of [1, 2, 5, 10]) {
    if (step * power >= length) return step * power;
  }
  return 10 * power;
}

function formatLength(metres) {
  return metres >= 1 ? `${metres} m` : `${Math.round(metres * 100)} cm`;
}

export class MapView {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{onCursor?: (world: {x:number,y:number}|null) => void,
   *          onViewChange?: () => void,
   *          onPoseDrag?: (pose: {x:number,y:number,theta:number}|null) => void,
   *          onPoseDrawn?: (pose: {x:number,y:number,theta:number}) => void,
   *          onPoseCancelled?: (why: 'short'|'escape'|'pointer') => void}} hooks
   */
  constructor(canvas, hooks = {}) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d', { alpha: false });
    this.hooks = hooks;

    // Map geometry from GET /api/v1/map.
    this.resolution = 0.01;
    this.tileSize = 64;
    this.origin = [0, 0];

    // key "x,y" -> {x, y, wanted, loaded, bitmap, queued, inFlight, epoch, dropped, failures}
    this.tiles = new Map();
    this.queue = [];
    this.activeFetches = 0;
    this.generation = 0;  // bumped by clearTiles(): late fetches of dropped tiles are ignored
    this.epoch = 0;       // bumped by beginSync()
    this.suspended = false;

    this.slam = [];       // [[x, y], ...]
    this.truth = [];
    this.lastPoseTime = -Infinity;
    this.robot = null;    // {x, y, theta}
    this.robotTruth = null;
    this.localized = true;  // false while slamd relocalises: this.robot is the last known pose

    this.tool = null;       // 'pose' while the set-pose tool is active
    this.poseDrag = null;   // {id, from: {x, y}, to: {x, y}, fromPx: [px, py], toPx} (world, CSS px)
    this.pendingPose = null;  // {x, y, theta}: sent to slamd, not yet answered
    this.places = [];  // where the robot may be while slamd is unsure (setPlaces)

    this.centre = { x: 0, y: 0 };
    this.scale = 100;     // CSS px per metre
    this.autoFit = true;  // until the user pans or zooms
    this.follow = false;  // keep the robot in the centre
    this.lastBounds = '';
    this.tilesDrawn = 0;
    this.renderQueued = false;

    this.installInput();
    new ResizeObserver(() => this.requestRender()).observe(canvas);
    this.watchPixelRatio();
    this.requestRender();
  }

  // ---- map tiles -------------------------------------------------------------------------

  /**
   * Starts a resynchronisation (after a reconnect, slamd may have restarted and numbered its
   * versions afresh): tiles announced from now on are current; the next setIndex() drops the
   * others unless it lists them.
   */
  beginSync({ restarted = false } = {}) {
    this.epoch += 1;
    if (restarted) {
      // Another slamd: a version it announces says nothing of the bitmaps of the last one, even
      // when the numbers coincide. They stay on screen until their replacements arrive.
      for (const tile of this.tiles.values()) tile.loaded = -1;
    }
  }

  /**
   * Stops fetching tiles (the event stream dropped: slamd is probably down or restarting). The
   * next setIndex() resumes, so no request goes out for a tile the new index no longer lists.
   */
  suspend() {
    this.suspended = true;
  }

  /** Takes the map index (GET /api/v1/map): its tiles and versions, geometry included. */
  setIndex(index) {
    this.resolution = index.resolution_m;
    this.tileSize = index.tile_size;
    this.origin = index.origin;
    for (const { x, y, version } of index.tiles) {
      const known = this.tiles.get(`${x},${y}`);
      // A tile announced since beginSync() is at least as recent as the index; any other
      // version may come from a previous slamd and is replaced, even by a smaller one.
      this.want(x, y, version, /*authoritative=*/known?.epoch !== this.epoch);
    }
    for (const [key, tile] of this.tiles) {
      if (tile.epoch !== this.epoch) this.dropTile(key, tile);
    }
    this.suspended = false;
    this.pump();
    this.boundsChanged();
  }

  /** Tiles announced by a `tiles` event: fetched again when their version is newer. */
  announceTiles(tiles) {
    for (const { x, y, version } of tiles) this.want(x, y, version, /*authoritative=*/false);
    this.boundsChanged();
  }

  /** Drops every tile (after a `reset` event). */
  clearTiles() {
    this.generation += 1;
    for (const [key, tile] of this.tiles) this.dropTile(key, tile);
    this.queue = [];
    this.requestRender();
  }

  get tileCount() {
    return this.tiles.size;
  }

  /** What the view holds of each tile, [{x, y, wanted, loaded}] (tests, the browser console). */
  tileVersions() {
    return [...this.tiles.values()].map(({ x, y, wanted, loaded }) => ({ x, y, wanted, loaded }));
  }

  want(x, y, version, authoritative) {
    const key = `${x},${y}`;
    let tile = this.tiles.get(key);
    if (!tile) {
      tile = { x, y, wanted: -1, loaded: -1, bitmap: null, queued: false, inFlight: false,
               epoch: this.epoch, dropped: false, failures: 0 };
      this.tiles.set(key, tile);
    }
    // A restarted slamd numbers versions afresh: the index may go backwards, and so may the
    // first announcement of a tile known only from before the resynchronisation began (a
    // `tiles` event that lands between beginSync() and the index reply). Within one
    // resynchronisation, versions only grow.
    const fresh = authoritative || tile.epoch !== this.epoch;
    tile.wanted = fresh ? version : Math.max(tile.wanted, version);
    tile.epoch = this.epoch;
    tile.failures = 0;
    if (tile.wanted !== tile.loaded) this.enqueue(tile);
  }

  dropTile(key, tile) {
    tile.dropped = true;
    tile.bitmap?.close();
    tile.bitmap = null;
    this.tiles.delete(key);
    this.requestRender();
  }

  enqueue(tile) {
    if (!tile.queued && !tile.inFlight) {
      tile.queued = true;
      this.queue.push(tile);
    }
    this.pump();
  }

  pump() {
    while (!this.suspended && this.activeFetches < kMaxConcurrentFetches && this.queue.length > 0) {
      const tile = this.queue.shift();
      tile.queued = false;
      if (!tile.dropped && tile.wanted !== tile.loaded) this.fetchTile(tile);
    }
  }

  async fetchTile(tile) {
    const generation = this.generation;
    const requested = tile.wanted;
    tile.inFlight = true;
    this.activeFetches += 1;
    let retry = false;
    try {
      const response = await fetch(`/api/v1/map/tiles/${tile.x}/${tile.y}.png?v=${requested}`);
      if (response.status === 404) {
        // The tile no longer exists (a reset raced with us): forget it.
        if (generation === this.generation && !tile.dropped) {
          this.dropTile(`${tile.x},${tile.y}`, tile);
        }
        return;
      }
      if (!response.ok) throw new Error(`tile ${tile.x},${tile.y}: HTTP ${response.status}`);
      const served = etagVersion(response.headers.get('ETag'));
      const bitmap = await createImageBitmap(await response.blob(), {
        colorSpaceConversion: 'none',  // keep the grey levels exact
        premultiplyAlpha: 'none',
      });
      if (generation !== this.generation || tile.dropped) {
        bitmap.close();
        return;
      }
      tile.bitmap?.close();
      tile.bitmap = bitmap;
      // The server sends the current tile, which may be newer than the one asked for.
      tile.loaded = Number.isFinite(served) ? Math.max(served, requested) : requested;
      if (tile.wanted < tile.loaded) tile.wanted = tile.loaded;
      this.requestRender();
    } catch {
      retry = true;  // slamd restarting or the network hiccuping: try again a little later
    } finally {
      tile.inFlight = false;
      this.activeFetches -= 1;
      tile.failures = retry ? tile.failures + 1 : 0;
      if (!tile.dropped && tile.wanted !== tile.loaded) {
        if (!retry) {
          this.enqueue(tile);
        } else if (tile.failures <= kMaxRetries) {
          const delay = kRetryDelayMs * 2 ** (tile.failures - 1);
          setTimeout(() => !tile.dropped && this.enqueue(tile), delay);
        }
        // Past that, the next announcement or resynchronisation of the tile fetches it again.
      }
      this.pump();
    }
  }

  // ---- trajectory ------------------------------------------------------------------------

  /** Replaces the trajectories (GET /api/v1/trajectory). Poses are [t, x, y, theta]. */
  setTrajectory(slam, groundTruth) {
    this.slam = slam.map(([, x, y]) => [x, y]);
    this.truth = (groundTruth ?? []).map(([, x, y]) => [x, y]);
    const last = slam.at(-1);
    this.lastPoseTime = last ? last[0] : -Infinity;
    this.robot = last ? { x: last[1], y: last[2], theta: last[3] } : null;
    const lastTruth = groundTruth?.at(-1);
    this.robotTruth = lastTruth ? { x: lastTruth[1], y: lastTruth[2], theta: lastTruth[3] } : null;
    this.boundsChanged();
    this.requestRender();
  }

  /** Appends the pose of a `pose` event (ignored if not newer than the last one). */
  appendPose(pose) {
    if (!(pose.t > this.lastPoseTime)) return false;
    this.lastPoseTime = pose.t;
    this.slam.push([pose.x, pose.y]);
    this.robot = { x: pose.x, y: pose.y, theta: pose.theta };
    if (pose.truth) {
      this.truth.push([pose.truth.x, pose.truth.y]);
      this.robotTruth = pose.truth;
    }
    if (this.follow && !this.holdsView) this.centre = { x: pose.x, y: pose.y };
    this.requestRender();
    return true;
  }

  clearTrajectory() {
    this.setTrajectory([], []);
  }

  /** Whether slamd knows where the robot is; while not, the robot is drawn as stale. */
  setLocalized(localized) {
    if (this.localized === localized) return;
    this.localized = localized;
    this.requestRender();
  }

  // ---- set-pose tool ---------------------------------------------------------------------

  /** Activates a tool ('pose') or none (null). While one is active the view holds still. */
  setTool(tool) {
    if (this.tool === tool) return;
    if (this.tool === 'pose') this.cancelPoseDrag('pointer');
    this.tool = tool;
    this.canvas.classList.toggle('tool-pose', tool === 'pose');
    if (!tool) {
      // Back to what the view did before: fitting, or following the robot.
      if (this.autoFit) this.fitNow();
      else if (this.follow && this.robot) this.centre = { x: this.robot.x, y: this.robot.y };
    }
    this.requestRender();
  }

  /** True while a tool holds the view still (no auto-fit, no follow). */
  get holdsView() {
    return this.tool !== null;
  }

  /** Cancels a pose drag under way; returns whether there was one. */
  cancelPoseDrag(why = 'escape') {
    if (!this.poseDrag) return false;
    const { id } = this.poseDrag;
    this.poseDrag = null;
    if (this.canvas.hasPointerCapture?.(id)) this.canvas.releasePointerCapture(id);
    this.requestRender();
    this.hooks.onPoseDrag?.(null);
    this.hooks.onPoseCancelled?.(why);
    return true;
  }

  /**
   * The places the robot may be while slamd is unsure (`{x, y, theta, score}`, best first; empty:
   * none), drawn as numbered rings.
   */
  setPlaces(places) {
    this.places = places;
    this.requestRender();
  }

  /** Shows a pose sent to slamd and not yet answered (null: none), as a dashed arrow. */
  showPendingPose(pose) {
    this.pendingPose = pose;
    this.requestRender();
  }

  /** The pose a drag means: at its start, facing the way it went (world frame). */
  static poseOfDrag(drag) {
    return {
      x: drag.from.x,
      y: drag.from.y,
      theta: Math.atan2(drag.to.y - drag.from.y, drag.to.x - drag.from.x),
    };
  }

  startPoseDrag(id, px, py) {
    const from = this.toWorld(px, py);
    this.poseDrag = { id, from, to: from, fromPx: [px, py], toPx: [px, py] };
    this.hooks.onPoseDrag?.(MapView.poseOfDrag(this.poseDrag));
    this.requestRender();
  }

  movePoseDrag(px, py) {
    this.poseDrag.to = this.toWorld(px, py);
    this.poseDrag.toPx = [px, py];
    this.hooks.onPoseDrag?.(MapView.poseOfDrag(this.poseDrag));
    this.requestRender();
  }

  endPoseDrag(px, py) {
    this.movePoseDrag(px, py);
    const drag = this.poseDrag;
    this.poseDrag = null;
    this.hooks.onPoseDrag?.(null);
    this.requestRender();
    const [dx, dy] = [drag.toPx[0] - drag.fromPx[0], drag.toPx[1] - drag.fromPx[1]];
    if (Math.hypot(dx, dy) < kMinPoseDragPx) {
      this.hooks.onPoseCancelled?.('short');
      return;
    }
    this.hooks.onPoseDrawn?.(MapView.poseOfDrag(drag));
  }

  // ---- view ------------------------------------------------------------------------------

  /** Fits the map and the trajectories in view, and keeps fitting as the map grows. */
  fit() {
    this.autoFit = true;
    this.setFollow(false);
    this.fitNow();
  }

  setFollow(on) {
    this.follow = on;
    if (on) {
      this.autoFit = false;
      if (this.robot) this.centre = { x: this.robot.x, y: this.robot.y };
      this.requestRender();
    }
    this.hooks.onViewChange?.();
  }

  bounds() {
    let minX = Infinity, minY = Infinity, maxX = -Infinity, maxY = -Infinity;
    const side = this.tileSize * this.resolution;
    for (const { x, y } of this.tiles.values()) {
      const x0 = this.origin[0] + x * side;
      const y0 = this.origin[1] + y * side;
      minX = Math.min(minX, x0); maxX = Math.max(maxX, x0 + side);
      minY = Math.min(minY, y0); maxY = Math.max(maxY, y0 + side);
    }
    for (const [x, y] of this.slam.concat(this.truth)) {
      minX = Math.min(minX, x); maxX = Math.max(maxX, x);
      minY = Math.min(minY, y); maxY = Math.max(maxY, y);
    }
    return Number.isFinite(minX) ? { minX, minY, maxX, maxY } : null;
  }

  boundsChanged() {
    if (!this.autoFit || this.holdsView) return;
    const b = this.bounds();
    const key = b ? `${b.minX},${b.minY},${b.maxX},${b.maxY}` : '';
    if (key !== this.lastBounds) this.fitNow();
  }

  fitNow() {
    const b = this.bounds();
    this.lastBounds = b ? `${b.minX},${b.minY},${b.maxX},${b.maxY}` : '';
    const width = this.canvas.clientWidth || 1;
    const height = this.canvas.clientHeight || 1;
    if (b) {
      const spanX = Math.max(b.maxX - b.minX, 0.5);
      const spanY = Math.max(b.maxY - b.minY, 0.5);
      this.centre = { x: (b.minX + b.maxX) / 2, y: (b.minY + b.maxY) / 2 };
      this.scale = clamp(0.92 * Math.min(width / spanX, height / spanY), kMinScale, kMaxScale);
    } else {
      this.centre = { x: 0, y: 0 };
      this.scale = 100;
    }
    this.requestRender();
  }

  /** World coordinates of a point in CSS pixels relative to the canvas. */
  toWorld(px, py) {
    return {
      x: this.centre.x + (px - this.canvas.clientWidth / 2) / this.scale,
      y: this.centre.y - (py - this.canvas.clientHeight / 2) / this.scale,
    };
  }

  /** The inverse of toWorld(): CSS pixels relative to the canvas of a world point. */
  toScreen(x, y) {
    return {
      px: this.canvas.clientWidth / 2 + (x - this.centre.x) * this.scale,
      py: this.canvas.clientHeight / 2 - (y - this.centre.y) * this.scale,
    };
  }

  zoomAt(px, py, factor) {
    const anchor = this.toWorld(px, py);
    this.scale = clamp(this.scale * factor, kMinScale, kMaxScale);
    // Keep the world point under the cursor where it was.
    this.centre = {
      x: anchor.x - (px - this.canvas.clientWidth / 2) / this.scale,
      y: anchor.y + (py - this.canvas.clientHeight / 2) / this.scale,
    };
    this.userMoved();
  }

  userMoved() {
    this.autoFit = false;
    if (this.follow) this.setFollow(false);
    this.requestRender();
  }

  installInput() {
    const canvas = this.canvas;
    let drag = null;
    const local = (event) => {
      const rect = canvas.getBoundingClientRect();
      return [event.clientX - rect.left, event.clientY - rect.top];
    };
    canvas.addEventListener('pointerdown', (event) => {
      if (event.button !== 0) return;
      canvas.setPointerCapture(event.pointerId);
      if (this.tool === 'pose') {
        if (!this.poseDrag) this.startPoseDrag(event.pointerId, ...local(event));
        return;
      }
      drag = { id: event.pointerId, at: local(event) };
      canvas.classList.add('dragging');
    });
    canvas.addEventListener('pointermove', (event) => {
      const [px, py] = local(event);
      if (this.poseDrag && this.poseDrag.id === event.pointerId) {
        this.movePoseDrag(px, py);
      } else if (drag && drag.id === event.pointerId) {
        const [dx, dy] = [px - drag.at[0], py - drag.at[1]];
        if (dx !== 0 || dy !== 0) {
          this.centre = { x: this.centre.x - dx / this.scale, y: this.centre.y + dy / this.scale };
          drag.at = [px, py];
          this.userMoved();
        }
      }
      this.hooks.onCursor?.(this.toWorld(px, py));
    });
    const endDrag = (event) => {
      if (this.poseDrag && this.poseDrag.id === event.pointerId) {
        if (event.type === 'pointerup') this.endPoseDrag(...local(event));
        else this.cancelPoseDrag('pointer');
      }
      if (drag && drag.id === event.pointerId) {
        drag = null;
        canvas.classList.remove('dragging');
      }
    };
    canvas.addEventListener('pointerup', endDrag);
    canvas.addEventListener('pointercancel', endDrag);
    canvas.addEventListener('pointerleave', () => this.hooks.onCursor?.(null));
    canvas.addEventListener('wheel', (event) => {
      event.preventDefault();
      const perLine = event.deltaMode === WheelEvent.DOM_DELTA_LINE ? 40 : 1;
      const [px, py] = local(event);
      this.zoomAt(px, py, Math.exp(-event.deltaY * perLine * 0.002));
    }, { passive: false });
    canvas.addEventListener('dblclick', (event) => {
      if (this.tool) return;  // two presses of a tool, not a zoom
      const [px, py] = local(event);
      this.zoomAt(px, py, event.shiftKey ? 0.5 : 2);
    });
  }

  /** Redraws when the device pixel ratio changes (browser zoom, another screen). */
  watchPixelRatio() {
    const query = matchMedia(`(resolution: ${devicePixelRatio}dppx)`);
    query.addEventListener('change', () => {
      this.requestRender();
      this.watchPixelRatio();
    }, { once: true });
  }

  // ---- drawing ---------------------------------------------------------------------------

  requestRender() {
    if (this.renderQueued) return;
    this.renderQueued = true;
    requestAnimationFrame(() => {
      this.renderQueued = false;
      this.render();
    });
  }

  render() {
    const canvas = this.canvas;
    const ratio = devicePixelRatio || 1;
    const width = Math.max(1, Math.round(canvas.clientWidth * ratio));
    const height = Math.max(1, Math.round(canvas.clientHeight * ratio));
    if (canvas.width !== width || canvas.height !== height) {
      canvas.width = width;
      canvas.height = height;
      if (this.autoFit && !this.holdsView) this.fitNow();
    }
    const ctx = this.ctx;
    const s = this.scale * ratio;  // device px per metre
    const sx = (x) => (x - this.centre.x) * s + width / 2;
    const sy = (y) => height / 2 - (y - this.centre.y) * s;

    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = kColours.background;
    ctx.fillRect(0, 0, width, height);

    // Tiles. A cell bigger than a device pixel is drawn as a crisp square; edges are rounded so
    // neighbouring tiles meet without seams.
    ctx.imageSmoothingEnabled = this.resolution * s < 1;
    const side = this.tileSize * this.resolution;
    let drawn = 0;
    for (const tile of this.tiles.values()) {
      if (!tile.bitmap) continue;
      const x0 = this.origin[0] + tile.x * side;
      const y0 = this.origin[1] + tile.y * side;
      const left = Math.round(sx(x0));
      const right = Math.round(sx(x0 + side));
      const top = Math.round(sy(y0 + side));  // PNG row 0 is the largest y
      const bottom = Math.round(sy(y0));
      if (right < 0 || left > width || bottom < 0 || top > height) continue;
      ctx.drawImage(tile.bitmap, left, top, right - left, bottom - top);
      drawn += 1;
    }
    this.tilesDrawn = drawn;

    // Trajectories: ground truth under the SLAM estimate.
    ctx.lineJoin = 'round';
    ctx.lineCap = 'round';
    // Ground truth as a wider band under the SLAM estimate, so both show where they coincide.
    this.drawPath(this.truth, sx, sy, kColours.truth, 4 * ratio);
    this.drawPath(this.slam, sx, sy, kColours.slam, 1.75 * ratio);
    if (this.robotTruth) {
      this.drawRobot(this.robotTruth, sx, sy, s, ratio, kColours.truthRobot, false);
    }
    if (this.robot && this.localized) {
      this.drawRobot(this.robot, sx, sy, s, ratio, kColours.robot, true);
    } else if (this.robot) {
      this.drawStaleRobot(this.robot, sx, sy, s, ratio);
    }
    const places = this.places;
    places.forEach((place, i) => this.drawPlace(place, i + 1, sx, sy, s, ratio));
    if (this.pendingPose) this.drawPoseArrow(this.pendingPose, null, sx, sy, s, ratio, true);
    if (this.poseDrag) {
      this.drawPoseArrow(MapView.poseOfDrag(this.poseDrag), this.poseDrag.to, sx, sy, s, ratio,
                         false);
    }

    this.drawScaleBar(ratio, height);

    const data = document.body.dataset;
    data.tilesDrawn = String(drawn);
    data.tilesLoaded = String([...this.tiles.values()].filter((t) => t.bitmap).length);
    data.trajectoryPoints = String(this.slam.length);
    data.truthPoints = String(this.truth.length);
    data.mapScale = this.scale.toFixed(2);
    data.localized = String(this.localized);
    data.places = String(places.length);
  }

  /** A place the robot may be: a ring with its heading and its rank beside it. */
  drawPlace(place, rank, sx, sy, s, ratio) {
    const ctx = this.ctx;
    this.drawRobot(place, sx, sy, s, ratio, kColours.place, false);
    const r = Math.max(kRobotRadiusM * s, 6 * ratio);
    ctx.font = `bold ${12 * ratio}px system-ui, sans-serif`;
    ctx.fillStyle = kColours.place;
    ctx.fillText(String(rank), sx(place.x) + r + 2 * ratio, sy(place.y) + r + 10 * ratio);
  }

  drawPath(points, sx, sy, colour, lineWidth) {
    if (points.length < 2) return;
    const ctx = this.ctx;
    ctx.beginPath();
    ctx.moveTo(sx(points[0][0]), sy(points[0][1]));
    for (let i = 1; i < points.length; ++i) ctx.lineTo(sx(points[i][0]), sy(points[i][1]));
    ctx.strokeStyle = colour;
    ctx.lineWidth = lineWidth;
    ctx.stroke();
  }

  /** The robot: a disc (real size, at least a few pixels) with a heading line. */
  drawRobot(pose, sx, sy, s, ratio, colour, filled) {
    const ctx = this.ctx;
    const x = sx(pose.x);
    const y = sy(pose.y);
    const r = Math.max(kRobotRadiusM * s, 6 * ratio);
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    if (filled) {
      ctx.fillStyle = 'rgba(21, 101, 192, 0.35)';
      ctx.fill();
    }
    ctx.strokeStyle = colour;
    ctx.lineWidth = 2 * ratio;
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x, y);
    ctx.lineTo(x + 1.7 * r * Math.cos(pose.theta), y - 1.7 * r * Math.sin(pose.theta));
    ctx.stroke();
  }

  /**
   * The robot while slamd relocalises: its last known pose, grey, hollow and dashed, labelled
   * (the pose is stale: slamd is searching the map for the robot).
   */
  drawStaleRobot(pose, sx, sy, s, ratio) {
    const ctx = this.ctx;
    ctx.save();
    ctx.setLineDash([4 * ratio, 3 * ratio]);
    this.drawRobot(pose, sx, sy, s, ratio, kColours.stale, false);
    ctx.restore();
    const r = Math.max(kRobotRadiusM * s, 6 * ratio);
    const label = 'relocalising…';
    ctx.font = `${12 * ratio}px system-ui, sans-serif`;
    const width = ctx.measureText(label).width;
    const x = sx(pose.x) + r + 4 * ratio;
    const y = sy(pose.y) - r - 4 * ratio;
    ctx.fillStyle = 'rgba(255, 255, 255, 0.85)';
    ctx.fillRect(x - 3 * ratio, y - 13 * ratio, width + 6 * ratio, 17 * ratio);
    ctx.fillStyle = '#424242';
    ctx.fillText(label, x, y);
  }

  /**
   * The pose tool's arrow: a robot-sized ring at the pose and an arrow along its heading, to
   * `tip` (the pointer) when given, else of a fixed length; dashed for a pose awaiting slamd.
   */
  drawPoseArrow(pose, tip, sx, sy, s, ratio, dashed) {
    const ctx = this.ctx;
    const x = sx(pose.x);
    const y = sy(pose.y);
    const r = Math.max(kRobotRadiusM * s, 6 * ratio);
    const dirX = Math.cos(pose.theta);
    const dirY = -Math.sin(pose.theta);  // screen y grows downwards
    const length = Math.max(tip ? Math.hypot(sx(tip.x) - x, sy(tip.y) - y) : 0, 2.2 * r,
                            24 * ratio);
    const [tipX, tipY] = [x + dirX * length, y + dirY * length];
    const head = Math.min(12 * ratio, 0.45 * length);
    ctx.save();
    ctx.strokeStyle = kColours.pose;
    ctx.fillStyle = kColours.pose;
    ctx.lineWidth = 2.5 * ratio;
    if (dashed) ctx.setLineDash([5 * ratio, 4 * ratio]);
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x, y);
    ctx.lineTo(tipX - dirX * head * 0.8, tipY - dirY * head * 0.8);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.beginPath();  // the head: a filled triangle at the tip
    ctx.moveTo(tipX, tipY);
    ctx.lineTo(tipX - dirX * head - dirY * head * 0.5, tipY - dirY * head + dirX * head * 0.5);
    ctx.lineTo(tipX - dirX * head + dirY * head * 0.5, tipY - dirY * head - dirX * head * 0.5);
    ctx.closePath();
    ctx.fill();
    ctx.restore();
  }

  drawScaleBar(ratio, height) {
    const ctx = this.ctx;
    const metres = niceLength(100 / this.scale);
    const length = metres * this.scale * ratio;
    const x = 12 * ratio;
    const y = height - 14 * ratio;
    ctx.fillStyle = 'rgba(255, 255, 255, 0.75)';
    ctx.fillRect(x - 6 * ratio, y - 20 * ratio, length + 12 * ratio, 28 * ratio);
    ctx.strokeStyle = kColours.scale;
    ctx.lineWidth = 2 * ratio;
    ctx.beginPath();
    ctx.moveTo(x, y - 5 * ratio);
    ctx.lineTo(x, y);
    ctx.lineTo(x + length, y);
    ctx.lineTo(x + length, y - 5 * ratio);
    ctx.stroke();
    ctx.fillStyle = kColours.scale;
    ctx.font = `${12 * ratio}px system-ui, sans-serif`;
    ctx.fillText(formatLength(metres), x + 4 * ratio, y - 7 * ratio);
  }
}

function clamp(value, low, high) {
  return Math.min(high, Math.max(low, value));
}
