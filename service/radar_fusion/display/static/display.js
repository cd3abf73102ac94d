// radar-fusion situation display: draws the frames the server pushes on /ws onto a canvas.
//
// Plane geometry (rings, grid, areas, radar sites) comes precomputed in system-plane metres
// from /api/scene; tracks carry plane x_m / y_m: the page only scales and translates.
// The map is drawn into an offscreen canvas when the view changes and copied under each
// frame; tracks are drawn in a handful of batched paths per frame (one per status and
// layer), so 4,000 tracks cost a few fillRect/lineTo per track plus the labels.
//
// The root element (#display) exposes what a test or a supervisor needs to read:
//   data-tracks        tracks drawn in the last frame (symbols with a finite position)
//   data-period        the period number of the TrackBatch drawn
//   data-frame-ms      time to draw the last frame (performance.now(), ms)
//   data-frame-ms-max  the longest draw so far, data-ingest-ms the last JSON.parse + ingest
//   data-frames        frames drawn, data-alerts open alerts, data-stca-lines STCA lines drawn
//   data-connected     the WebSocket is open
"use strict";

(() => {
  const COLOURS = {
    background: "#0a121c",
    grid: "#1b2a3a",
    gridText: "#46607a",
    ring: "#253a52",
    ringText: "#4f6d8c",
    confirmed: "#44e36b",
    coasting: "#ffc400",
    tentative: "#8fa3b8",
    stca: "#ff4040",
    apw: "#ff5cf0",
    msaw: "#ff9a1f",
    apwArea: "rgba(255, 92, 240, 0.10)",
    apwEdge: "rgba(255, 92, 240, 0.65)",
    msaArea: "rgba(255, 154, 31, 0.06)",
    msaEdge: "rgba(255, 154, 31, 0.45)",
    radarLive: "#6fb6ff",
    radarDead: "#d9534f", // not the STCA red: a silent radar is not a conflict
    selected: "#ffffff",
  };
  const STATUS_COLOUR = [COLOURS.confirmed, COLOURS.coasting, COLOURS.tentative];
  const STATUS_NAME = ["confirmed", "coasting", "tentative"];
  const KT_PER_MPS = 3600 / 1852;
  const M_PER_NM = 1852;
  const TRAIL_POINTS = 6; // positions kept per track, the current one included
  const LABEL_FONT = "11px 'DejaVu Sans Mono', 'Liberation Mono', monospace";
  const PICK_RADIUS_PX = 10;

  const root = document.getElementById("display");
  const canvas = document.getElementById("scope");
  const ctx = canvas.getContext("2d");
  const mapLayer = document.createElement("canvas");
  const mapCtx = mapLayer.getContext("2d");
  const ui = {
    clock: document.getElementById("clock"),
    count: document.getElementById("count"),
    conn: document.getElementById("conn"),
    vector: document.getElementById("vector"),
    labels: document.getElementById("labels"),
    trails: document.getElementById("trails"),
    scale: document.getElementById("scale"),
    details: document.getElementById("track-details"),
    alerts: document.getElementById("alert-list"),
    radars: document.getElementById("radar-list"),
    health: document.getElementById("health"),
    displayStats: document.getElementById("display-stats"),
  };

  const state = {
    scene: null,
    tracks: null, // the last tracks frame (columnar)
    index: new Map(), // track id -> row of state.tracks
    trails: new Map(), // track id -> {x: Float64Array, y: Float64Array, n, head, period}
    alerts: [],
    alertByTrack: new Map(), // track id -> [alert, ...]
    health: null,
    radarStatus: {},
    selectedId: null,
    view: { cx: 0, cy: 0, pxPerM: 0.002 }, // centre of the screen in plane metres, scale
    userMoved: false,
    autoFits: 0,
    mapDirty: true,
    framePending: false,
    frames: 0,
    frameMsMax: 0,
    width: 0,
    height: 0,
    dpr: 1,
    tracksAgeS: null, // wall seconds since the server's newest TrackBatch (its "display" frames)
    staleAfterS: null, // beyond, the picture is stale: greyed, and the header says so
    stale: false,
    alpha: 1.0, // the track layer's opacity: 0.3 while stale
  };

  // ------------------------------------------------------------------ view
  const sx = (x) => state.width / 2 + (x - state.view.cx) * state.view.pxPerM;
  const sy = (y) => state.height / 2 - (y - state.view.cy) * state.view.pxPerM;
  const planeX = (px) => state.view.cx + (px - state.width / 2) / state.view.pxPerM;
  const planeY = (py) => state.view.cy - (py - state.height / 2) / state.view.pxPerM;

  function resize() {
    const rect = canvas.getBoundingClientRect();
    state.dpr = window.devicePixelRatio || 1;
    state.width = Math.max(1, Math.round(rect.width));
    state.height = Math.max(1, Math.round(rect.height));
    for (const c of [canvas, mapLayer]) {
      c.width = Math.round(state.width * state.dpr);
      c.height = Math.round(state.height * state.dpr);
    }
    state.mapDirty = true;
    requestDraw();
  }

  function fit(xMin, xMax, yMin, yMax) {
    const w = Math.max(xMax - xMin, 5000);
    const h = Math.max(yMax - yMin, 5000);
    state.view.cx = (xMin + xMax) / 2;
    state.view.cy = (yMin + yMax) / 2;
    state.view.pxPerM = 0.92 * Math.min(state.width / w, state.height / h);
    state.mapDirty = true;
    requestDraw();
  }

  function fitCoverage() {
    if (!state.scene) return;
    const e = state.scene.extent_m;
    fit(-e, e, -e, e);
  }

  function fitTraffic() {
    const f = state.tracks;
    if (!f || f.n === 0) return fitCoverage();
    // confirmed and coasting tracks only: a tentative one is often a false plot far out
    const firm = f.status.some((s) => s !== 2);
    let xMin = Infinity, xMax = -Infinity, yMin = Infinity, yMax = -Infinity;
    for (let i = 0; i < f.n; i++) {
      if (firm && f.status[i] === 2) continue;
      const x = f.x_m[i], y = f.y_m[i];
      if (x < xMin) xMin = x;
      if (x > xMax) xMax = x;
      if (y < yMin) yMin = y;
      if (y > yMax) yMax = y;
    }
    const m = 0.08 * Math.max(xMax - xMin, yMax - yMin) + 10 * M_PER_NM;
    fit(xMin - m, xMax + m, yMin - m, yMax + m);
  }

  function zoomAt(px, py, factor) {
    const x = planeX(px), y = planeY(py);
    state.view.pxPerM = Math.min(Math.max(state.view.pxPerM * factor, 1e-5), 0.5);
    state.view.cx = x - (px - state.width / 2) / state.view.pxPerM;
    state.view.cy = y + (py - state.height / 2) / state.view.pxPerM;
    state.userMoved = true;
    state.mapDirty = true;
    requestDraw();
  }

  // ------------------------------------------------------------------ the map layer
  function polyline(c, xs, ys, close) {
    if (!xs.length) return;
    c.moveTo(sx(xs[0]), sy(ys[0]));
    for (let i = 1; i < xs.length; i++) c.lineTo(sx(xs[i]), sy(ys[i]));
    if (close) c.closePath();
  }

  function degLabel(deg, pos, neg) {
    const a = Math.abs(deg);
    let d = Math.floor(a + 1e-9);
    let m = Math.round((a - d) * 60);
    if (m === 60) { d += 1; m = 0; }
    return `${d}°${m ? String(m).padStart(2, "0") + "'" : ""}${deg >= 0 ? pos : neg}`;
  }

  function drawMap() {
    const c = mapCtx;
    c.setTransform(state.dpr, 0, 0, state.dpr, 0, 0);
    c.fillStyle = COLOURS.background;
    c.fillRect(0, 0, state.width, state.height);
    const scene = state.scene;
    if (!scene) return;
    c.font = LABEL_FONT;
    c.lineWidth = 1;
    // MSA and APW areas, filled even-odd (holes stay open)
    for (const [areas, fill, edge, text] of [
      [scene.msa_areas, COLOURS.msaArea, COLOURS.msaEdge, (a) => `MSA ${a.id} ${Math.round(a.min_alt_ft)} ft`],
      [scene.apw_areas, COLOURS.apwArea, COLOURS.apwEdge,
        (a) => `${a.id} FL${Math.max(0, Math.round(a.lower_fl))}-${Math.round(a.upper_fl)}`],
    ]) {
      for (const a of areas) {
        c.beginPath();
        for (const r of a.rings) polyline(c, r.x, r.y, true);
        c.fillStyle = fill;
        c.fill("evenodd");
        c.strokeStyle = edge;
        c.setLineDash(areas === scene.msa_areas ? [6, 4] : []);
        c.stroke();
        c.setLineDash([]);
        const r0 = a.rings[0];
        let xMin = Infinity, yMax = -Infinity;
        for (let i = 0; i < r0.x.length; i++) { xMin = Math.min(xMin, r0.x[i]); yMax = Math.max(yMax, r0.y[i]); }
        c.fillStyle = edge;
        c.fillText(text(a), sx(xMin) + 3, sy(yMax) + 12);
      }
    }
    // lat/lon grid
    c.beginPath();
    for (const g of scene.grid) polyline(c, g.x, g.y, false);
    c.strokeStyle = COLOURS.grid;
    c.stroke();
    c.fillStyle = COLOURS.gridText;
    for (const g of scene.grid) {
      // label each line where it enters the screen's left (parallels) or bottom (meridians) edge
      const n = g.x.length;
      for (let i = 0; i < n; i++) {
        const px = sx(g.x[i]), py = sy(g.y[i]);
        if (g.kind === "parallel" && px >= 2 && py > 12 && py < state.height - 4) {
          c.fillText(degLabel(g.deg, "N", "S"), px + 2, py - 2);
          break;
        }
        if (g.kind === "meridian" && py <= state.height - 4 && px > 2 && px < state.width - 40) {
          c.fillText(degLabel(g.deg, "E", "W"), px + 2, py - 2);
          break;
        }
      }
    }
    // range rings around the system centre, labelled at their north point
    const ringEvery = state.view.pxPerM * scene.ring_step_nm * M_PER_NM < 25 ? 5 : 1; // thin out when zoomed out
    c.beginPath();
    for (const r of scene.rings) {
      if (Math.round(r.range_nm / scene.ring_step_nm) % ringEvery) continue;
      polyline(c, r.x, r.y, true);
    }
    c.strokeStyle = COLOURS.ring;
    c.stroke();
    c.fillStyle = COLOURS.ringText;
    for (const r of scene.rings) {
      if (Math.round(r.range_nm / scene.ring_step_nm) % ringEvery) continue;
      c.fillText(`${r.range_nm} NM`, sx(r.x[0]) + 3, sy(r.y[0]) - 3);
    }
    // centre cross
    const x0 = sx(0), y0 = sy(0);
    c.beginPath();
    c.moveTo(x0 - 6, y0); c.lineTo(x0 + 6, y0); c.moveTo(x0, y0 - 6); c.lineTo(x0, y0 + 6);
    c.strokeStyle = COLOURS.ringText;
    c.stroke();
    // map scale bar: a round number of NM close to 120 px
    const nmPerPx = 1 / (state.view.pxPerM * M_PER_NM);
    let nm = 1;
    for (const step of [1, 2, 5, 10, 20, 25, 50, 100, 200, 500]) if (step / nmPerPx <= 140) nm = step;
    ui.scale.style.width = `${Math.round(nm / nmPerPx)}px`;
    ui.scale.textContent = `${nm} NM`;
  }

  // ------------------------------------------------------------------ tracks
  function ident(f, i) {
    const cs = f.callsign[i];
    if (cs) return cs;
    const a = f.mode3a[i];
    if (a != null) return "A" + a.toString(8).padStart(4, "0");
    return "#" + f.id[i];
  }

  function levelLine(f, i) {
    const fl = f.fl[i];
    const vr = f.vrate_fpm[i];
    const level = state.scene ? state.scene.level_vrate_fpm : 400;
    const arrow = vr == null ? " " : vr > level ? "↑" : vr < -level ? "↓" : " ";
    const flText = fl == null ? "---" : String(Math.round(fl)).padStart(3, "0");
    // a track of one update has no velocity yet (null): no speed shown
    const gs = f.vx_mps[i] == null ? "---" : Math.round(Math.hypot(f.vx_mps[i], f.vy_mps[i]) * KT_PER_MPS);
    return `${flText}${arrow} ${gs}`;
  }

  function ingestTracks(f) {
    if (f.new_stream) {
      // the daemon restarted without its state: its track ids were given to other aircraft
      state.trails.clear();
      state.alerts = [];
      updateAlerts();
    }
    const index = new Map();
    for (let i = 0; i < f.n; i++) index.set(f.id[i], i);
    // trails: append this period's position, forget the tracks that are gone
    for (const id of state.trails.keys()) if (!index.has(id)) state.trails.delete(id);
    for (let i = 0; i < f.n; i++) {
      const id = f.id[i];
      let tr = state.trails.get(id);
      if (!tr) {
        tr = { x: new Float64Array(TRAIL_POINTS), y: new Float64Array(TRAIL_POINTS), n: 0, head: 0, period: -1 };
        state.trails.set(id, tr);
      }
      if (tr.period === f.period) continue;
      tr.period = f.period;
      tr.x[tr.head] = f.x_m[i];
      tr.y[tr.head] = f.y_m[i];
      tr.head = (tr.head + 1) % TRAIL_POINTS;
      tr.n = Math.min(tr.n + 1, TRAIL_POINTS);
    }
    state.tracks = f;
    state.index = index;
    if (!state.userMoved && state.autoFits < 3 && f.n > 0) { // the first batches: frame the traffic
      state.autoFits++;
      fitTraffic();
    }
  }

  function drawTracks(c) {
    const f = state.tracks;
    if (!f) return { drawn: 0, stcaLines: 0 };
    state.alpha = state.stale ? 0.3 : 1.0; // a stale picture is not shown as the present
    c.globalAlpha = state.alpha;
    try {
      return drawTrackLayer(c, f);
    } finally {
      c.globalAlpha = 1.0;
    }
  }

  // Label placement: each label takes the first of four places around its symbol (right
  // above, then left above, right below, left below) whose box no label placed before it
  // covers, on a grid of LABEL_CELL px; the alerted tracks' first, then by status. A label
  // with no free place takes the least covered (counted in data-label-overlaps).
  const LABEL_CELL = 6;
  const LABEL_W = 96, LABEL_H = 24; // two lines of 11 px monospace, up to 14 characters
  const LABEL_PLACES = [
    [10, -10], // the label's first baseline, from the symbol: right above
    [-10 - LABEL_W, -10], // left above
    [10, 24], // right below
    [-10 - LABEL_W, 24], // left below
  ];

  function drawLabels(c, f, px, py, W, H) {
    c.font = LABEL_FONT;
    c.textBaseline = "alphabetic";
    const cols = Math.ceil((W + 2 * LABEL_W) / LABEL_CELL), rows = Math.ceil((H + 4 * LABEL_H) / LABEL_CELL);
    const taken = new Uint8Array(cols * rows);
    const box = (x, y, h) => { // cells of a label box whose first baseline is at (x, y)
      const c0 = Math.floor((x + LABEL_W) / LABEL_CELL), c1 = Math.floor((x + 2 * LABEL_W) / LABEL_CELL);
      const r0 = Math.floor((y - 10 + 2 * LABEL_H) / LABEL_CELL), r1 = Math.floor((y - 10 + h + 2 * LABEL_H) / LABEL_CELL);
      return [Math.max(c0, 0), Math.min(c1, cols - 1), Math.max(r0, 0), Math.min(r1, rows - 1)];
    };
    const covered = ([c0, c1, r0, r1]) => { // cells of the box that labels placed before cover
      let n = 0;
      for (let r = r0; r <= r1; r++) for (let k = c0; k <= c1; k++) n += taken[r * cols + k];
      return n;
    };
    const take = ([c0, c1, r0, r1]) => {
      for (let r = r0; r <= r1; r++) taken.fill(1, r * cols + c0, r * cols + c1 + 1);
    };
    const order = [];
    for (const id of state.alertByTrack.keys()) {
      const i = state.index.get(id);
      if (i !== undefined) order.push(i);
    }
    for (let s = 0; s < 3; s++) {
      for (let i = 0; i < f.n; i++) if (f.status[i] === s && !state.alertByTrack.has(f.id[i])) order.push(i);
    }
    const leader = new Path2D();
    let overlaps = 0;
    for (const i of order) {
      const x = px[i], y = py[i];
      if (!(x >= -80 && x <= W && y >= -10 && y <= H + 40)) continue;
      const alerts = state.alertByTrack.get(f.id[i]);
      const h = alerts ? LABEL_H + 12 : LABEL_H;
      let place = LABEL_PLACES[0], least = Infinity;
      for (const p of LABEL_PLACES) {
        const n = covered(box(x + p[0], y + p[1], h));
        if (n < least) [place, least] = [p, n];
        if (n === 0) break;
      }
      if (least > 0) overlaps++;
      const lx = x + place[0], ly = y + place[1];
      take(box(lx, ly, h));
      c.fillStyle = alerts ? COLOURS[alerts[0].kind] : STATUS_COLOUR[f.status[i]];
      const ms = f.mode_s[i];
      c.fillText(ms ? `${ident(f, i)} ${ms}` : ident(f, i), lx, ly);
      c.fillText(levelLine(f, i), lx, ly + 11);
      if (alerts) c.fillText(alerts.map((a) => alertTag(a)).join(" "), lx, ly + 22);
      // the leader: from the symbol's corner towards the label's nearest corner
      const right = place[0] > 0, below = place[1] > 0;
      leader.moveTo(x + (right ? 4 : -4), y + (below ? 4 : -4));
      leader.lineTo(right ? lx - 1 : lx + LABEL_W + 1, below ? ly - 10 : ly + 1);
    }
    c.strokeStyle = "rgba(200, 214, 229, 0.35)";
    c.stroke(leader);
    root.dataset.labelOverlaps = String(overlaps);
  }

  function drawTrackLayer(c, f) {
    const n = f.n;
    const vectorS = Number(ui.vector.value);
    const showTrails = ui.trails.checked;
    const W = state.width, H = state.height;
    const px = new Float32Array(n), py = new Float32Array(n);
    let drawn = 0;
    for (let i = 0; i < n; i++) {
      px[i] = sx(f.x_m[i]);
      py[i] = sy(f.y_m[i]);
      if (Number.isFinite(px[i]) && Number.isFinite(py[i])) drawn++;
    }
    for (let s = 0; s < 3; s++) {
      const colour = STATUS_COLOUR[s];
      // history trail: the earlier positions as dots
      if (showTrails) {
        c.beginPath();
        for (let i = 0; i < n; i++) {
          if (f.status[i] !== s) continue;
          const tr = state.trails.get(f.id[i]);
          if (!tr) continue;
          for (let k = 2; k <= tr.n; k++) { // k = 1 is the current position
            const j = (tr.head - k + TRAIL_POINTS) % TRAIL_POINTS;
            c.rect(sx(tr.x[j]) - 1, sy(tr.y[j]) - 1, 2, 2);
          }
        }
        c.globalAlpha = 0.55 * state.alpha;
        c.fillStyle = colour;
        c.fill();
        c.globalAlpha = state.alpha;
      }
      // speed vector: where the track will be in vectorS seconds at its present velocity
      if (vectorS > 0) {
        c.beginPath();
        for (let i = 0; i < n; i++) {
          if (f.status[i] !== s || f.vx_mps[i] == null) continue;
          c.moveTo(px[i], py[i]);
          c.lineTo(px[i] + f.vx_mps[i] * vectorS * state.view.pxPerM, py[i] - f.vy_mps[i] * vectorS * state.view.pxPerM);
        }
        c.strokeStyle = colour;
        c.lineWidth = 1;
        c.stroke();
      }
      // the symbol: confirmed a filled square, coasting an open diamond, tentative a small circle
      c.beginPath();
      for (let i = 0; i < n; i++) {
        if (f.status[i] !== s) continue;
        const x = px[i], y = py[i];
        if (s === 0) c.rect(x - 3.5, y - 3.5, 7, 7);
        else if (s === 1) { c.moveTo(x, y - 5); c.lineTo(x + 5, y); c.lineTo(x, y + 5); c.lineTo(x - 5, y); c.closePath(); }
        else { c.moveTo(x + 3, y); c.arc(x, y, 3, 0, 2 * Math.PI); }
      }
      if (s === 0) { c.fillStyle = colour; c.fill(); }
      else { c.strokeStyle = colour; c.lineWidth = s === 1 ? 1.5 : 1; c.stroke(); }
    }
    // safety nets: STCA pairs joined in red with the time to closest approach; APW / MSAW rings
    let stcaLines = 0;
    c.lineWidth = 2;
    c.font = LABEL_FONT;
    for (const a of state.alerts) {
      if (a.kind === "stca" && a.track_ids.length === 2) {
        const i = state.index.get(a.track_ids[0]), j = state.index.get(a.track_ids[1]);
        if (i === undefined || j === undefined) continue;
        c.beginPath();
        c.moveTo(px[i], py[i]);
        c.lineTo(px[j], py[j]);
        c.arc(px[i], py[i], 9, 0, 2 * Math.PI);
        c.moveTo(px[j] + 9, py[j]);
        c.arc(px[j], py[j], 9, 0, 2 * Math.PI);
        c.strokeStyle = COLOURS.stca;
        c.stroke();
        const ttc = a.time_to_cpa_s == null ? "" : ` ${Math.round(a.time_to_cpa_s)}s`;
        c.fillStyle = COLOURS.stca;
        c.fillText(`STCA${ttc}`, (px[i] + px[j]) / 2 + 6, (py[i] + py[j]) / 2 - 6);
        stcaLines++;
      } else if (a.kind === "apw" || a.kind === "msaw") {
        for (const id of a.track_ids) {
          const i = state.index.get(id);
          if (i === undefined) continue;
          c.beginPath();
          c.arc(px[i], py[i], a.kind === "apw" ? 12 : 15, 0, 2 * Math.PI);
          c.strokeStyle = COLOURS[a.kind];
          c.stroke();
        }
      }
    }
    c.lineWidth = 1;
    // labels (only of the tracks on screen): ident + Mode S, then FL, climb/descent arrow, GS (kt)
    if (ui.labels.checked) drawLabels(c, f, px, py, W, H);
    // the selected track
    if (state.selectedId !== null) {
      const i = state.index.get(state.selectedId);
      if (i !== undefined) {
        c.strokeStyle = COLOURS.selected;
        c.lineWidth = 1.5;
        c.strokeRect(px[i] - 8, py[i] - 8, 16, 16);
        c.lineWidth = 1;
      }
    }
    return { drawn, stcaLines };
  }

  function alertTag(a) {
    if (a.kind === "stca") return `STCA ${a.time_to_cpa_s == null ? "" : Math.round(a.time_to_cpa_s) + "s"}`;
    if (a.kind === "apw") {
      const t = a.time_to_entry_s == null ? "" : ` ${Math.round(a.time_to_entry_s)}s`;
      return `APW ${a.area_id || ""}${t}`;
    }
    const t = a.time_to_violation_s == null ? "" : ` ${Math.round(a.time_to_violation_s)}s`;
    return `MSAW${t}`;
  }

  function drawRadars(c) {
    if (!state.scene) return;
    const radars = (state.health && state.health.radars) || {};
    c.font = LABEL_FONT;
    for (const r of state.scene.radars) {
      const h = radars[r.id];
      const live = h ? h.live : null;
      const x = sx(r.x_m), y = sy(r.y_m);
      c.beginPath();
      c.moveTo(x, y - 7); c.lineTo(x + 6, y + 5); c.lineTo(x - 6, y + 5); c.closePath();
      c.strokeStyle = live === false ? COLOURS.radarDead : COLOURS.radarLive;
      c.lineWidth = 1.5;
      c.stroke();
      c.fillStyle = c.strokeStyle;
      c.fillText(live === false ? `${r.id} (silent)` : r.id, x + 8, y + 4);
    }
    c.lineWidth = 1;
  }

  // ------------------------------------------------------------------ the frame
  function requestDraw() {
    if (state.framePending) return;
    state.framePending = true;
    requestAnimationFrame(draw);
  }

  function draw() {
    state.framePending = false;
    const t0 = performance.now();
    if (state.mapDirty) {
      drawMap();
      state.mapDirty = false;
    }
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(mapLayer, 0, 0);
    ctx.setTransform(state.dpr, 0, 0, state.dpr, 0, 0);
    drawRadars(ctx);
    const { drawn, stcaLines } = drawTracks(ctx);
    const ms = performance.now() - t0;
    state.frames++;
    if (state.tracks) state.frameMsMax = Math.max(state.frameMsMax, ms);
    root.dataset.tracks = String(drawn);
    root.dataset.period = state.tracks ? String(state.tracks.period) : "-1";
    root.dataset.frameMs = ms.toFixed(1);
    root.dataset.frameMsMax = state.frameMsMax.toFixed(1);
    root.dataset.frames = String(state.frames);
    root.dataset.alerts = String(state.alerts.length);
    root.dataset.stcaLines = String(stcaLines);
    ui.count.textContent = `${drawn} tracks`;
    if (state.tracks) ui.clock.textContent = clock(state.tracks.t);
    updateDetails();
  }

  // ------------------------------------------------------------------ side panel
  function text(tag, content, cls) {
    const el = document.createElement(tag);
    el.textContent = content;
    if (cls) el.className = cls;
    return el;
  }

  function kv(dl, pairs) {
    dl.replaceChildren();
    for (const [k, v, cls] of pairs) {
      dl.append(text("dt", k), text("dd", v, cls));
    }
  }

  const fmt = (v, digits = 0, unit = "") => (v == null ? "–" : `${Number(v).toFixed(digits)}${unit}`);

  function updateDetails() {
    const id = state.selectedId;
    if (id === null) return;
    const f = state.tracks;
    const i = f ? state.index.get(id) : undefined;
    if (i === undefined) {
      ui.details.replaceChildren(text("div", `track ${id}: no longer tracked`, "muted"));
      return;
    }
    const noV = f.vx_mps[i] == null; // one update: no velocity yet
    const gsKt = noV ? NaN : Math.hypot(f.vx_mps[i], f.vy_mps[i]) * KT_PER_MPS;
    const hdg = noV ? NaN : (Math.atan2(f.vx_mps[i], f.vy_mps[i]) * 180 / Math.PI + 360) % 360;
    const dl = document.createElement("dl");
    dl.className = "kv";
    kv(dl, [
      ["track", `${f.id[i]} ${STATUS_NAME[f.status[i]]}`, f.status[i] === 0 ? "good" : "warn"],
      ["ident", ident(f, i)],
      ["Mode S", f.mode_s[i] || "–"],
      ["FL", fmt(f.fl[i], 0)],
      ["vert. rate", fmt(f.vrate_fpm[i], 0, " ft/min")],
      ["ground speed", noV ? "– (one update)" : `${gsKt.toFixed(0)} kt`],
      ["track (grid)", noV ? "–" : `${hdg.toFixed(0).padStart(3, "0")}°`],
      ["lat / lon", `${f.lat_deg[i].toFixed(4)} ${f.lon_deg[i].toFixed(4)}`],
      ["x / y", `${(f.x_m[i] / 1000).toFixed(2)} ${(f.y_m[i] / 1000).toFixed(2)} km`],
      ["σ position", fmt(f.sigma_m[i], 0, " m")],
      ["radars", f.sources[i] || "none (coasting)"],
      ["updates", String(f.updates[i])],
      ["age", fmt(f.age_s[i], 0, " s")],
      ["manoeuvre", f.manoeuvre_prob[i] == null ? "–" : `${Math.round(100 * f.manoeuvre_prob[i])} %`],
    ]);
    const alerts = state.alertByTrack.get(id) || [];
    const box = [dl];
    for (const a of alerts) box.push(text("div", alertTag(a), `${a.kind}-t`));
    ui.details.replaceChildren(...box);
  }

  function clock(t) {
    const d = new Date(t * 1000);
    return Number.isNaN(d.getTime()) ? "--:--:--Z" : d.toISOString().slice(11, 19) + "Z";
  }

  function updateFreshness() {
    const age = state.tracksAgeS, after = state.staleAfterS;
    const stale = age != null && after != null && age > after;
    const changed = stale !== state.stale;
    state.stale = stale;
    root.dataset.stale = String(stale);
    if (root.dataset.connected === "true") {
      ui.conn.textContent = stale ? `NO TRACK DATA for ${Math.round(age)} s` : state.tracks ? "live" : "waiting for tracks";
      ui.conn.className = stale ? "bad" : "good";
    }
    return changed;
  }

  function identOf(id) {
    const f = state.tracks;
    const i = f ? state.index.get(id) : undefined;
    return i === undefined ? `#${id}` : ident(f, i);
  }

  function updateAlerts() {
    state.alertByTrack = new Map();
    for (const a of state.alerts) {
      for (const id of a.track_ids) {
        if (!state.alertByTrack.has(id)) state.alertByTrack.set(id, []);
        state.alertByTrack.get(id).push(a);
      }
    }
    if (!state.alerts.length) {
      ui.alerts.replaceChildren(text("li", "none", "muted"));
      return;
    }
    const items = state.alerts.map((a) => {
      let extra = "";
      if (a.kind === "stca") {
        extra = ` sep ${fmt(a.min_sep_m == null ? null : a.min_sep_m / M_PER_NM, 1, " NM")} / ${fmt(a.min_vsep_ft, 0, " ft")}`;
      } else if (a.kind === "msaw") {
        extra = ` MSA ${fmt(a.min_alt_ft, 0, " ft")}`;
      }
      return text("li", `${alertTag(a)} ${a.track_ids.map(identOf).join("–")}${extra}`, `${a.kind}-t`);
    });
    ui.alerts.replaceChildren(...items);
  }

  function updateHealth() {
    const h = state.health;
    const radarItems = [];
    if (state.scene) {
      for (const r of state.scene.radars) {
        const rh = h && h.radars ? h.radars[r.id] : undefined;
        const st = state.radarStatus[r.id];
        const live = rh ? (rh.live ? "live" : "silent") : "?";
        const cls = rh ? (rh.live ? (rh.clock_suspect ? "warn" : "good") : "bad") : "muted";
        const extra = rh ? ` ${rh.plots} plots${rh.clock_suspect ? ", clock suspect" : ""}` : "";
        const last = st ? ` · ${st.kind} ${clock(st.t)}` : "";
        radarItems.push(text("li", `● ${r.id} ${live}${extra}${last}`, cls));
      }
    }
    ui.radars.replaceChildren(...radarItems);
    if (!h) return;
    const rejected = Object.entries(h.rejected || {}).filter(([, n]) => n > 0).sort((a, b) => b[1] - a[1]);
    const total = rejected.reduce((s, [, n]) => s + n, 0);
    const c = h.counters || {};
    const pairs = [
      ["periods closed", String(h.periods_closed)],
      ["tracks", String(h.tracks)],
      ["period p50 / p99", `${fmt(h.processing_ms_p50, 1)} / ${fmt(h.processing_ms_p99, 1)} ms`],
      // a replay of old data is days behind the wall clock: no lag to speak of
      ["lag (wall − event)", h.lag_s != null && Math.abs(h.lag_s) > 86400 ? "– (replayed data)" : fmt(h.lag_s, 1, " s")],
      ["plots accepted", fmt(c.plots_accepted)],
      ["plots wild", fmt(c.plots_wild)],
      ["rejected", String(total), total ? "warn" : ""],
    ];
    for (const [reason, n] of rejected.slice(0, 6)) pairs.push([`  ${reason}`, String(n), "warn"]);
    pairs.push(["uptime", fmt(h.uptime_s, 0, " s")]);
    kv(ui.health, pairs);
  }

  function updateDisplayStats(d) {
    const skipped = Object.values(d.rejected || {}).reduce((s, n) => s + n, 0);
    const r = d.received || {};
    kv(ui.displayStats, [
      ["batches received", fmt(r.tracks)],
      ["alerts / health msgs", `${fmt(r.alerts)} / ${fmt(r.health)}`],
      ["skipped (malformed)", String(skipped), skipped ? "warn" : ""],
      ["coalesced at server", fmt(d.tracks_coalesced)],
      ["dropped for this page", fmt(d.client ? d.client.frames_dropped : null), d.client && d.client.frames_dropped ? "warn" : ""],
      ["server decode", fmt(d.decode_ms_last, 1, " ms")],
      ["page draw (last / max)", `${root.dataset.frameMs || "–"} / ${root.dataset.frameMsMax || "–"} ms`],
      ["page ingest", `${root.dataset.ingestMs || "–"} ms`],
    ]);
  }

  // ------------------------------------------------------------------ the feed
  function onMessage(ev) {
    const t0 = performance.now();
    let msg;
    try {
      msg = JSON.parse(ev.data);
    } catch (e) {
      return; // the server only sends JSON; nothing to draw from anything else
    }
    switch (msg.type) {
      case "tracks":
        ingestTracks(msg);
        updateAlerts(); // the alerts' names: a reload sends the alerts before their tracks
        state.tracksAgeS = 0; // this one is new (a reload's replayed frame is aged by the "display" frame after it)
        updateFreshness();
        root.dataset.ingestMs = (performance.now() - t0).toFixed(1);
        break;
      case "alerts":
        state.alerts = msg.alerts;
        updateAlerts();
        break;
      case "health":
        state.health = msg.health;
        updateHealth();
        break;
      case "radars":
        state.radarStatus = msg.status;
        updateHealth();
        return; // the side panel only: the scope draws each radar's liveness from health
      case "display":
        updateDisplayStats(msg);
        state.tracksAgeS = msg.tracks_age_s;
        state.staleAfterS = msg.tracks_stale_after_s;
        if (!updateFreshness()) return;
        break;
      default:
        return;
    }
    requestDraw();
  }

  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${proto}//${location.host}/ws`);
    ws.onopen = () => {
      root.dataset.connected = "true";
      ui.conn.textContent = "connected";
      ui.conn.className = "muted";
    };
    ws.onmessage = onMessage;
    ws.onclose = () => {
      root.dataset.connected = "false";
      ui.conn.textContent = "disconnected, retrying";
      ui.conn.className = "bad";
      setTimeout(connect, 2000);
    };
  }

  async function loadScene() {
    try {
      const resp = await fetch("/api/scene");
      state.scene = await resp.json();
    } catch (e) {
      setTimeout(loadScene, 2000);
      return;
    }
    for (const w of state.scene.warnings || []) ui.alerts.before(text("div", w, "warn"));
    if (!state.userMoved && !state.tracks) fitCoverage();
    state.mapDirty = true;
    updateHealth();
    requestDraw();
  }

  // ------------------------------------------------------------------ interaction
  let drag = null;
  canvas.addEventListener("mousedown", (e) => {
    drag = { x: e.offsetX, y: e.offsetY, cx: state.view.cx, cy: state.view.cy, moved: false };
  });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const rect = canvas.getBoundingClientRect();
    const dx = e.clientX - rect.left - drag.x, dy = e.clientY - rect.top - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 3) drag.moved = true;
    if (!drag.moved) return;
    state.view.cx = drag.cx - dx / state.view.pxPerM;
    state.view.cy = drag.cy + dy / state.view.pxPerM;
    state.userMoved = true;
    state.mapDirty = true;
    requestDraw();
  });
  window.addEventListener("mouseup", (e) => {
    if (drag && !drag.moved && e.target === canvas) pick(e.offsetX, e.offsetY);
    drag = null;
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    zoomAt(e.offsetX, e.offsetY, Math.exp(-e.deltaY * 0.0015));
  }, { passive: false });
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    const step = 80;
    if (e.key === "+" || e.key === "=") zoomAt(state.width / 2, state.height / 2, 1.25);
    else if (e.key === "-") zoomAt(state.width / 2, state.height / 2, 0.8);
    else if (e.key === "f" || e.key === "F") fitTraffic();
    else if (e.key === "h" || e.key === "H") fitCoverage();
    else if (e.key === "Escape") { state.selectedId = null; ui.details.replaceChildren(text("div", "click a track", "muted")); requestDraw(); }
    else if (e.key.startsWith("Arrow")) {
      const d = { ArrowLeft: [-step, 0], ArrowRight: [step, 0], ArrowUp: [0, step], ArrowDown: [0, -step] }[e.key];
      state.view.cx += d[0] / state.view.pxPerM;
      state.view.cy += d[1] / state.view.pxPerM;
      state.userMoved = true;
      state.mapDirty = true;
      requestDraw();
    }
  });

  function pick(px, py) {
    const f = state.tracks;
    if (!f) return;
    let best = -1, bestD2 = PICK_RADIUS_PX * PICK_RADIUS_PX;
    for (let i = 0; i < f.n; i++) {
      const dx = sx(f.x_m[i]) - px, dy = sy(f.y_m[i]) - py;
      const d2 = dx * dx + dy * dy;
      if (d2 <= bestD2) { bestD2 = d2; best = i; }
    }
    state.selectedId = best >= 0 ? f.id[best] : null;
    if (best < 0) ui.details.replaceChildren(text("div", "click a track", "muted"));
    else updateDetails();
    requestDraw();
  }

  document.getElementById("fit").addEventListener("click", () => { state.userMoved = true; fitTraffic(); });
  document.getElementById("home").addEventListener("click", () => { state.userMoved = true; fitCoverage(); });
  for (const el of [ui.vector, ui.labels, ui.trails]) el.addEventListener("change", requestDraw);
  window.addEventListener("resize", resize);

  // a test hook, read-only: the track under a given id's screen position (for click tests)
  window.radarFusionDisplay = {
    screenOf(id) {
      const i = state.index.get(id);
      return i === undefined ? null : { x: sx(state.tracks.x_m[i]), y: sy(state.tracks.y_m[i]) };
    },
  };

  resize();
  loadScene();
  connect();
})();
