// The live map (issue 12): every track the daemon serves, from its event stream
// (GET api/v1/stream: `track`, `retire` and `stats` events), drawn on Leaflet over the
// embedded world outline. No polling: one EventSource, reconnected by the browser (and by us
// when the browser gives up), and one history request per aircraft when it first appears.
//
// Responsiveness with 1,000 aircraft (2,000 events a second):
// - events only record the newest state per aircraft; everything is drawn once per
//   animation frame;
// - the aircraft (icons and labels) are one canvas, redrawn whole when something moved:
//   1,000 DOM markers cost far more in style, layout and compositing than drawing them;
// - trails, ellipses and predictions are Leaflet vectors on its canvas renderer, refreshed
//   within a time budget per frame (the oldest first), only in and near the view, ellipses
//   only when they would be larger than a pixel, trails when they gain a point;
// - the aircraft list draws only the rows in sight; the land and range rings have a canvas
//   of their own that never redraws for aircraft.

import { covarianceEllipse, ellipseLatLngs, offsetLatLon } from "./geo.js";

const L = window.L;
const topojson = window.topojson;
const SETTINGS = JSON.parse(document.getElementById("map-settings").textContent);

/** Flight modes: label, colour, meaning. */
const MODES = [
  ["CV", "#2f6fd6", "constant velocity"],
  ["CA", "#e08600", "along-track acceleration"],
  ["CT", "#d62f5b", "coordinated turn"],
  ["CH", "#1f9e55", "climb or descent"],
  ["CHCA", "#8b4fd0", "climb or descent, accelerating"],
];
const COLOUR = Object.fromEntries(MODES.map(([m, c]) => [m, c]));
const colourOf = (mode) => COLOUR[mode] ?? "#6b7280";

/** Ellipses and prediction circles at this many sigma. */
const SIGMA_K = 2;
/** Vertices of an uncertainty ellipse. */
const ELLIPSE_VERTICES = 36;
/** An ellipse is drawn when its major semi-axis spans at least this many pixels. */
const ELLIPSE_MIN_PX = 1.5;
/** Points kept in a trail. */
const TRAIL_MAX_POINTS = 600;
/** A trail point at most every this much feed time, s. */
const TRAIL_STEP_S = 1;
/** History requests in flight at once (a thousand aircraft appear at once on connect). */
const HISTORY_CONCURRENCY = 4;
/** Vectors are refreshed in passes this far apart, ms: each pass makes Leaflet redraw its
 * whole canvas, whatever the number of vectors changed. */
const VECTOR_PERIOD_MS = 250;
/** Time a pass may take, ms; the rest waits for the next pass (oldest first). */
const VECTOR_BUDGET_MS = 10;
/** The aircraft list is sorted and counted at most this often, ms. */
const LIST_REFRESH_MS = 500;
/** Height of a row of the list, px (map.css: #list td; measured after each drawing). */
let rowH = 20;
let rowMeasured = false;
/** Height of the list's header row, px (measured once). */
let headH = 0;
/** The side panel is redrawn at most this often, ms. */
const PANEL_REFRESH_MS = 250;
/** A click selects the aircraft whose icon centre is within this, px. */
const HIT_PX = 12;
/** Reconnection delays when the browser gives up on the stream, ms. */
const RECONNECT_MIN_MS = 1000;
const RECONNECT_MAX_MS = 30000;

const FT_PER_M = 1 / 0.3048;
const KT_PER_MPS = 3600 / 1852;
/** Equatorial circumference of Leaflet's sphere, m (metres per pixel at a zoom). */
const EARTH_CIRCUMFERENCE_M = 40075016.686;

const $ = (id) => document.getElementById(id);
const esc = (s) =>
  String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
const fin = (x) => typeof x === "number" && Number.isFinite(x);
const fmt = (x, digits) => (fin(x) ? x.toFixed(digits) : "-");

/** icao -> Aircraft on the page. */
const aircraft = new Map();
/** Newest state per aircraft, not yet drawn. */
const pending = new Map();
/** Aircraft retired, not yet removed. */
const retired = new Set();
/** Aircraft whose vectors wait for a refresh, oldest first. */
const vectorQueue = new Set();
let selected = null;
/** The canvas of the aircraft (AircraftCanvas, made once the map has its layers). */
let aircraftCanvas = null;

// ---------------------------------------------------------------------------------------
// The map and its layers.

const map = L.map("map", { preferCanvas: true, worldCopyJump: true, minZoom: 2, zoomSnap: 0.5, zoomControl: true });
map.createPane("land").style.zIndex = 250;
map.createPane("aircraft").style.zIndex = 650;
map.getPane("aircraft").style.pointerEvents = "none";
const staticRenderer = L.canvas({ pane: "land", padding: 0.2 });
const renderer = L.canvas({ padding: 0.1 });

const land = L.layerGroup();
const trails = L.layerGroup().addTo(map);
const ellipses = L.layerGroup().addTo(map);
const predictions = L.layerGroup().addTo(map);
/** Every aircraft's prediction circles: off by default (at +120 s in a manoeuvre they span
 * tens of km); the selected aircraft's are always drawn (selectedCircles). */
const predictionCircles = L.layerGroup();
const selectedCircles = L.layerGroup().addTo(map);
const rings = L.layerGroup().addTo(map);
const labels = L.layerGroup().addTo(map);

fetch("assets/vendor/world-atlas/land-110m.json")
  .then((r) => r.json())
  .then((topo) => {
    L.geoJSON(topojson.feature(topo, topo.objects.land), {
      renderer: staticRenderer,
      interactive: false,
      style: { color: "#9c9a8c", weight: 0.8, fillColor: "#f1eee4", fillOpacity: 1 },
    }).addTo(land);
  })
  .catch((e) => console.warn("world outline:", e));

const bases = {};
if (SETTINGS.tiles) {
  const tiles = L.tileLayer(SETTINGS.tiles.url, {
    maxZoom: SETTINGS.tiles.max_zoom,
    attribution: esc(SETTINGS.tiles.attribution),
  });
  bases["Tiles"] = tiles.addTo(map);
  bases["Outline"] = land;
} else {
  land.addTo(map);
}
map.attributionControl.addAttribution("Natural Earth");
L.control
  .layers(Object.keys(bases).length ? bases : null, {
    Trails: trails,
    [`${SIGMA_K}\u03c3 uncertainty`]: ellipses,
    Predictions: predictions,
    [`Prediction ${SIGMA_K}\u03c3, every aircraft`]: predictionCircles,
    "Range rings": rings,
    Labels: labels,
  })
  .addTo(map);

const legend = L.control({ position: "bottomright" });
legend.onAdd = () => {
  const div = L.DomUtil.create("div", "legend");
  const horizons = (SETTINGS.prediction_horizons_s ?? []).map((h) => `+${h} s`).join(", ");
  div.innerHTML =
    MODES.map(([m, c, what]) => `<div class="row"><span class="swatch" style="background:${c}"></span><b>${m}</b> ${what}</div>`).join("") +
    `<div class="note">Shaded: ${SIGMA_K}\u03c3 position ellipse. Dashed: predicted path at ${esc(horizons)}; ` +
    `circles: its ${SIGMA_K}\u03c3 (selected aircraft; all from the layer menu). Red outline: diverging.</div>`;
  L.DomEvent.disableClickPropagation(div);
  return div;
};
legend.addTo(map);

let fitted = false;
/** Set by the first `stats` event: the state the server sends first is in by then. */
let fitDue = false;
/** True while the view pans or zooms. */
let moving = false;
map.on("movestart zoomstart", () => (moving = true));
map.on("moveend zoomend", () => (moving = false));

if (SETTINGS.receiver && fin(SETTINGS.receiver.lat_deg) && fin(SETTINGS.receiver.lon_deg)) {
  const { lat_deg: lat, lon_deg: lon } = SETTINGS.receiver;
  L.circleMarker([lat, lon], { renderer: staticRenderer, radius: 4, color: "#111", weight: 2, fillColor: "#fff", fillOpacity: 1, interactive: false }).addTo(rings);
  let outer = 0;
  for (const km of SETTINGS.range_rings_km ?? []) {
    outer = Math.max(outer, km);
    L.circle([lat, lon], { renderer: staticRenderer, radius: km * 1000, color: "#4a5866", weight: 1, dashArray: "3 5", fill: false, interactive: false }).addTo(rings);
    L.tooltip({ permanent: true, direction: "center", className: "ring-label" })
      .setLatLng(offsetLatLon(lat, lon, 0, km * 1000))
      .setContent(`${km} km`)
      .addTo(rings);
  }
  const r = Math.max(outer, 100) * 1000;
  map.fitBounds([offsetLatLon(lat, lon, -r, -r), offsetLatLon(lat, lon, r, r)]);
} else {
  map.setView([30, 0], 2);
}

// ---------------------------------------------------------------------------------------
// Aircraft.


class Aircraft {
  constructor(t) {
    this.icao = t.icao;
    this.track = t;
    this.trail = [];
    this.trailT = [];
    this.trailChanged = false;
    this.shown = false;
    this.mode = null;
    this.trailLine = L.polyline([], { renderer, weight: 1.5, opacity: 0.7, interactive: false });
    this.ellipse = L.polygon([], { renderer, weight: 1, opacity: 0.8, fillOpacity: 0.18, interactive: false });
    this.predLine = L.polyline([], { renderer, weight: 1.2, opacity: 0.8, dashArray: "4 4", interactive: false });
    this.predCircles = [];
  }

  /** Takes state `t`; its vectors are refreshed later, within the frame's budget. */
  update(t) {
    this.track = t;
    this.extendTrail(t.t, t.lat, t.lon);
    this.applyFilter();
    vectorQueue.add(this);
  }

  extendTrail(t, lat, lon) {
    let last = this.trailT.length ? this.trailT[this.trailT.length - 1] : -Infinity;
    // Feed time went back (a new time base): the old trail belongs to another time line.
    if (fin(t) && t + 60 < last) {
      this.trail = [];
      this.trailT = [];
      last = -Infinity;
    }
    if (fin(t) && t - last >= TRAIL_STEP_S) {
      this.trail.push([lat, lon]);
      this.trailT.push(t);
      if (this.trail.length > TRAIL_MAX_POINTS) {
        this.trail.shift();
        this.trailT.shift();
      }
      this.trailChanged = true;
    }
  }

  /** History points (oldest first) before the first point heard live. */
  prependHistory(points) {
    const first = this.trailT.length ? this.trailT[0] : Infinity;
    const older = points.filter((p) => fin(p.t) && fin(p.lat) && fin(p.lon) && p.t < first);
    const keep = older.slice(Math.max(0, older.length - (TRAIL_MAX_POINTS - this.trail.length)));
    this.trail = keep.map((p) => [p.lat, p.lon]).concat(this.trail);
    this.trailT = keep.map((p) => p.t).concat(this.trailT);
    this.trailChanged = true;
    vectorQueue.add(this);
  }

  /** Brings the trail, ellipse and predictions up to date with the state (`view`: the
   * padded bounds of the view and metres per pixel there). */
  drawVectors(view) {
    const t = this.track;
    if (!t || !this.shown) return;
    if (t.mode !== this.mode) {
      const c = colourOf(t.mode);
      for (const v of [this.trailLine, this.ellipse, this.predLine, ...this.predCircles]) v.setStyle({ color: c });
      this.mode = t.mode;
    }
    if (this.trailChanged && map.hasLayer(trails)) {
      this.trailLine.setLatLngs(this.trail);
      this.trailChanged = false;
    }
    if (map.hasLayer(ellipses)) {
      const e = covarianceEllipse(t.pos_cov_enu_m2, SIGMA_K);
      const mPerPx = view.metresPerPixel * Math.cos((t.lat * Math.PI) / 180);
      const big = e && e.major_m >= ELLIPSE_MIN_PX * mPerPx;
      const pts = big ? ellipseLatLngs(t.lat, t.lon, t.pos_cov_enu_m2, SIGMA_K, ELLIPSE_VERTICES) : null;
      if (pts) this.ellipse.setLatLngs(pts);
      else if (this.ellipse.getLatLngs().flat().length) this.ellipse.setLatLngs([]);
    }
    if (map.hasLayer(predictions) || this.icao === selected) this.drawPredictions(t);
  }

  drawPredictions(t) {
    const preds = Array.isArray(t.predictions) ? t.predictions.filter((p) => fin(p.lat) && fin(p.lon)) : [];
    this.predLine.setLatLngs([[t.lat, t.lon], ...preds.map((p) => [p.lat, p.lon])]);
    const circles = this.icao === selected || map.hasLayer(predictionCircles);
    if (!circles) return;
    while (this.predCircles.length < preds.length) {
      const c = L.circle([t.lat, t.lon], { renderer, radius: 1, weight: 1, opacity: 0.7, fillOpacity: 0.06, color: colourOf(t.mode), interactive: false });
      this.predCircles.push(c);
      if (this.shown) c.addTo(this.icao === selected ? selectedCircles : predictionCircles);
    }
    while (this.predCircles.length > preds.length) {
      const c = this.predCircles.pop();
      predictionCircles.removeLayer(c);
      selectedCircles.removeLayer(c);
    }
    preds.forEach((p, i) => {
      const c = this.predCircles[i];
      c.setLatLng([p.lat, p.lon]);
      c.setRadius(fin(p.pos_sigma_m) ? SIGMA_K * p.pos_sigma_m : 0);
    });
  }

  /** Shows or hides the aircraft as the list's filters say. */
  applyFilter() {
    const show = matches(this.track);
    if (show === this.shown) return;
    this.shown = show;
    const pairs = [
      [trails, this.trailLine],
      [ellipses, this.ellipse],
      [predictions, this.predLine],
      ...this.predCircles.map((c) => [this.icao === selected ? selectedCircles : predictionCircles, c]),
    ];
    for (const [group, layer] of pairs) {
      if (show) group.addLayer(layer);
      else group.removeLayer(layer);
    }
    if (show) {
      this.trailChanged = true;
      vectorQueue.add(this);
    }
  }

  remove() {
    this.shown = false;
    this.track = null;
    vectorQueue.delete(this);
    trails.removeLayer(this.trailLine);
    ellipses.removeLayer(this.ellipse);
    predictions.removeLayer(this.predLine);
    for (const c of this.predCircles) {
      predictionCircles.removeLayer(c);
      selectedCircles.removeLayer(c);
    }
  }
}

function altFt(t) {
  return fin(t.alt_m) ? t.alt_m * FT_PER_M : null;
}

function labelLines(t) {
  const name = t.callsign || t.icao;
  if (t.on_ground) return [name, "GND"];
  const ft = altFt(t);
  const arrow = t.vertical === "climb" ? " \u2191" : t.vertical === "descent" ? " \u2193" : "";
  return [name, `${ft === null ? "-" : Math.round(ft / 100) * 100} ft${arrow}`];
}

/** Plane silhouette pointing north, centred on 0,0 (20 px across). */
const PLANE = new Path2D(
  "M0,-9 L1.3,-3 L8.5,1.2 L8.5,2.8 L1.3,0.9 L0.9,5.6 L3.2,7.4 L3.2,8.6 L0,7.8 L-3.2,8.6 L-3.2,7.4 L-0.9,5.6 L-1.3,0.9 L-8.5,2.8 L-8.5,1.2 L-1.3,-3 Z",
);
/** Side of an icon sprite, CSS px. */
const SPRITE_PX = 28;
/** Icons are drawn rotated to the nearest this many degrees (one sprite each). */
const SPRITE_STEP_DEG = 5;
/** Pre-drawn icons: `colour|angle|diverging|ground|dpr` -> canvas. At most 6 colours x 72
 * angles x 4 = 1,728 sprites of 28x28 px. Copying a sprite costs a fraction of filling and
 * stroking the path, which matters 1,000 times a drawing. */
const sprites = new Map();

function planeSprite(colour, trackDeg, diverging, ground, dpr) {
  const angle = (Math.round((fin(trackDeg) ? trackDeg : 0) / SPRITE_STEP_DEG) * SPRITE_STEP_DEG) % 360;
  const key = `${colour}|${angle}|${diverging ? 1 : 0}|${ground ? 1 : 0}|${dpr}`;
  let c = sprites.get(key);
  if (c) return c;
  c = document.createElement("canvas");
  c.width = c.height = Math.ceil(SPRITE_PX * dpr);
  const x = c.getContext("2d");
  x.setTransform(dpr, 0, 0, dpr, c.width / 2, c.height / 2);
  x.rotate((angle * Math.PI) / 180);
  x.lineJoin = "round";
  if (diverging) {
    x.lineWidth = 4;
    x.strokeStyle = "#e0001b";
    x.stroke(PLANE);
  }
  x.globalAlpha = ground ? 0.6 : 1;
  x.fillStyle = colour;
  x.fill(PLANE);
  x.lineWidth = 1.2;
  x.strokeStyle = "#fff";
  x.stroke(PLANE);
  sprites.set(key, c);
  return c;
}

/** A label's two lines drawn once on a canvas of their own, redrawn when the text changes. */
function labelSprite(a, dpr) {
  const [l1, l2] = labelLines(a.track);
  const text = `${l1}\n${l2}|${dpr}`;
  if (a.label?.text === text) return a.label;
  const measure = labelSprite.ctx ?? (labelSprite.ctx = document.createElement("canvas").getContext("2d"));
  measure.font = LABEL_FONT;
  const w = Math.ceil(Math.max(measure.measureText(l1).width, measure.measureText(l2).width)) + 6;
  const h = 26;
  const c = a.label?.canvas ?? document.createElement("canvas");
  c.width = Math.ceil(w * dpr);
  c.height = Math.ceil(h * dpr);
  const x = c.getContext("2d");
  x.setTransform(dpr, 0, 0, dpr, 0, 0);
  x.font = LABEL_FONT;
  x.textBaseline = "top";
  x.lineJoin = "round";
  x.lineWidth = 3;
  x.strokeStyle = "rgba(255,255,255,0.9)";
  x.fillStyle = "#102";
  for (const [line, y] of [[l1, 1], [l2, 13]]) {
    x.strokeText(line, 2, y);
    x.fillText(line, 2, y);
  }
  a.label = { text, canvas: c, w, h };
  return a.label;
}
const LABEL_FONT = "10.5px system-ui, sans-serif";

/**
 * Every shown aircraft on one canvas over the map: icon rotated by the track, coloured by
 * mode (red outline while diverging, a ring when selected), callsign and altitude label
 * (labels that would overlap one already drawn are left out). Redrawn whole: at once when
 * the view moves or the user selects or filters, and for new data at most every
 * aircraft.size / 10 ms (10 times a second with 1,000 aircraft: each moves twice a second at
 * most, and a pixel in minutes); hidden during zoom animations.
 */
const AircraftCanvas = L.Layer.extend({
  onAdd(m) {
    this._canvas = L.DomUtil.create("canvas", "aircraft-canvas leaflet-zoom-hide", m.getPane("aircraft"));
    this._ctx = this._canvas.getContext("2d");
    /** icao -> [x, y] in the map container, as last drawn. */
    this.drawn = new Map();
    this._queued = false;
    this._timer = null;
    this._last = 0;
    m.on("move moveend zoomend viewreset resize", this.redraw, this);
    this.redraw();
  },
  onRemove(m) {
    m.off("move moveend zoomend viewreset resize", this.redraw, this);
    L.DomUtil.remove(this._canvas);
  },
  /** Redraws in the next frame; `throttled`: new data only, no sooner than the period. */
  redraw(throttled) {
    if (this._queued || !this._map) return;
    const wait = throttled === true ? this._last + Math.min(200, aircraft.size / 10) - performance.now() : 0;
    if (wait > 0) {
      if (!this._timer) this._timer = setTimeout(() => ((this._timer = null), this.redraw()), wait);
      return;
    }
    clearTimeout(this._timer);
    this._timer = null;
    this._queued = true;
    requestAnimationFrame(() => {
      this._queued = false;
      this._last = performance.now();
      this._draw();
    });
  },
  _draw() {
    const m = this._map;
    if (!m) return;
    const size = m.getSize();
    const dpr = window.devicePixelRatio || 1;
    const c = this._canvas;
    if (c.width !== Math.round(size.x * dpr) || c.height !== Math.round(size.y * dpr)) {
      c.width = Math.round(size.x * dpr);
      c.height = Math.round(size.y * dpr);
      c.style.width = `${size.x}px`;
      c.style.height = `${size.y}px`;
    }
    L.DomUtil.setPosition(c, m.containerPointToLayerPoint([0, 0]));
    const ctx = this._ctx;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, c.width, c.height);
    this.drawn.clear();
    const order = [];
    for (const a of aircraft.values()) {
      if (!a.shown) continue;
      const t = a.track;
      const p = m.latLngToContainerPoint([t.lat, t.lon]);
      if (p.x < -20 || p.y < -20 || p.x > size.x + 20 || p.y > size.y + 20) continue;
      this.drawn.set(a.icao, [p.x, p.y]);
      order.push([a, p]);
    }
    const half = Math.ceil(SPRITE_PX * dpr) / 2;
    for (const [a, p] of order) {
      const t = a.track;
      const sprite = planeSprite(colourOf(t.mode), t.track_deg, t.diverging, t.on_ground, dpr);
      ctx.drawImage(sprite, Math.round(p.x * dpr - half), Math.round(p.y * dpr - half));
    }
    const sel = order.findIndex(([a]) => a.icao === selected);
    if (sel >= 0) {
      const [, p] = order[sel];
      ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      ctx.beginPath();
      ctx.arc(p.x, p.y, 13, 0, 2 * Math.PI);
      ctx.lineWidth = 2.5;
      ctx.strokeStyle = "#111";
      ctx.stroke();
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      // Its label first: never left out.
      if (sel > 0) order.unshift(order.splice(sel, 1)[0]);
    }
    if (m.hasLayer(labels)) this._labels(ctx, dpr, order, size);
  },
  _labels(ctx, dpr, order, size) {
    // Occupied cells of a coarse grid: a label over one already drawn is left out.
    const CELL = 8;
    const taken = new Set();
    for (const [a, p] of order) {
      const x = p.x + 10;
      const y = p.y - 11;
      if (x > size.x) continue;
      const label = labelSprite(a, dpr);
      const cells = [];
      let free = true;
      for (let cx = Math.floor(x / CELL); cx <= Math.floor((x + label.w) / CELL) && free; cx++) {
        for (let cy = Math.floor(y / CELL); cy <= Math.floor((y + label.h) / CELL); cy++) {
          const k = cx * 100003 + cy;
          if (taken.has(k)) {
            free = false;
            break;
          }
          cells.push(k);
        }
      }
      if (!free) continue;
      for (const k of cells) taken.add(k);
      ctx.drawImage(label.canvas, Math.round(x * dpr), Math.round(y * dpr));
    }
  },
  /** The drawn aircraft nearest to a container point, within HIT_PX. */
  hit(point) {
    let best = null;
    let bestD = HIT_PX;
    for (const [icao, [x, y]] of this.drawn) {
      const d = Math.hypot(x - point.x, y - point.y);
      if (d <= bestD) {
        best = icao;
        bestD = d;
      }
    }
    return best;
  },
});
aircraftCanvas = new AircraftCanvas().addTo(map);

map.on("click", (e) => {
  const icao = aircraftCanvas.hit(e.containerPoint);
  if (icao) select(icao, false);
});
map.on("mousemove", (e) => {
  map.getContainer().style.cursor = aircraftCanvas.hit(e.containerPoint) ? "pointer" : "";
});
function queueAllVectors() {
  for (const a of aircraft.values()) {
    a.trailChanged = true;
    vectorQueue.add(a);
  }
  queueFrame();
}

// History: one request per new aircraft, a few at a time.
const historyQueue = [];
let historyInFlight = 0;
function requestHistory(icao) {
  historyQueue.push(icao);
  pumpHistory();
}
function pumpHistory() {
  while (historyInFlight < HISTORY_CONCURRENCY && historyQueue.length) {
    const icao = historyQueue.shift();
    if (!aircraft.has(icao)) continue;
    historyInFlight++;
    fetch(`api/v1/tracks/${encodeURIComponent(icao)}/history`)
      .then((r) => (r.ok ? r.json() : null))
      .then((h) => {
        const a = aircraft.get(icao);
        if (a && a.track && h && Array.isArray(h.points)) {
          a.prependHistory(h.points);
          queueFrame();
        }
      })
      .catch(() => {})
      .finally(() => {
        historyInFlight--;
        pumpHistory();
      });
  }
}

// ---------------------------------------------------------------------------------------
// Filters, list and panel.

const filters = { text: "", modes: new Set(MODES.map(([m]) => m)), altMin: null, altMax: null };
let sortKey = "callsign";
let sortDir = 1;

function matches(t) {
  if (!t) return false;
  if (!filters.modes.has(t.mode) && COLOUR[t.mode]) return false;
  if (filters.text) {
    const q = filters.text;
    if (!t.icao.includes(q) && !(t.callsign ?? "").toLowerCase().includes(q)) return false;
  }
  if (filters.altMin !== null || filters.altMax !== null) {
    const ft = t.on_ground ? 0 : altFt(t);
    if (ft === null) return false;
    if (filters.altMin !== null && ft < filters.altMin) return false;
    if (filters.altMax !== null && ft > filters.altMax) return false;
  }
  return true;
}

const SORT = {
  callsign: (t) => (t.callsign || "~" + t.icao).toLowerCase(),
  icao: (t) => t.icao,
  mode: (t) => t.mode,
  alt: (t) => altFt(t) ?? -1e9,
  gs: (t) => t.ground_speed_mps ?? -1,
  vs: (t) => t.vertical_rate_mps ?? 0,
  sigma: (t) => t.pos_sigma_m ?? 1e12,
  messages: (t) => t.messages ?? 0,
};

$("f-modes").innerHTML = MODES.map(
  ([m, c]) => `<label style="color:${c}"><input type="checkbox" value="${m}" checked>${m}</label>`,
).join("");

function onFilterChange() {
  filters.text = $("f-search").value.trim().toLowerCase();
  filters.modes = new Set([...$("f-modes").querySelectorAll("input:checked")].map((i) => i.value));
  const num = (id) => {
    const v = $(id).value.trim();
    return v === "" || !Number.isFinite(Number(v)) ? null : Number(v);
  };
  filters.altMin = num("f-alt-min");
  filters.altMax = num("f-alt-max");
  for (const a of aircraft.values()) a.applyFilter();
  aircraftCanvas.redraw();
  renderList();
  queueFrame();
}
for (const id of ["f-search", "f-alt-min", "f-alt-max"]) $(id).addEventListener("input", onFilterChange);
$("f-modes").addEventListener("change", onFilterChange);

document.querySelector("#list thead").addEventListener("click", (e) => {
  const key = e.target.closest("th")?.dataset.key;
  if (!key) return;
  sortDir = key === sortKey ? -sortDir : 1;
  sortKey = key;
  renderList();
});
$("list-rows").addEventListener("click", (e) => {
  const icao = e.target.closest("tr")?.dataset.icao;
  if (icao) select(icao, true);
});

/** The list's rows, filtered and sorted; only those in sight are in the DOM. */
let listTracks = [];
let listRendered = 0;
let listDirty = true;
function renderList() {
  listRendered = performance.now();
  listDirty = false;
  listTracks = [...aircraft.values()].map((a) => a.track).filter(matches);
  const key = SORT[sortKey];
  const keyed = listTracks.map((t) => [key(t), t]);
  keyed.sort(([x, a], [y, b]) => (x < y ? -1 : x > y ? 1 : 0) * sortDir || (a.icao < b.icao ? -1 : 1));
  listTracks = keyed.map(([, t]) => t);
  for (const th of document.querySelectorAll("#list th")) {
    th.classList.toggle("sorted", th.dataset.key === sortKey);
    th.classList.toggle("asc", sortDir > 0);
    th.classList.toggle("desc", sortDir < 0);
  }
  $("list-count").textContent = `${listTracks.length} of ${aircraft.size} aircraft`;
  renderRows();
}

let rowsQueued = false;
$("list-scroll").addEventListener("scroll", () => {
  if (rowsQueued) return;
  rowsQueued = true;
  requestAnimationFrame(() => {
    rowsQueued = false;
    renderRows();
  });
});

/** The rows in sight, between two spacers of the height of those that are not. */
function renderRows() {
  const scroller = $("list-scroll");
  // Heights measured once (reading them forces a layout).
  headH ||= document.querySelector("#list thead").offsetHeight;
  const first = Math.max(0, Math.floor((scroller.scrollTop - headH) / rowH) - 5);
  const count = Math.ceil(scroller.clientHeight / rowH) + 10;
  const last = Math.min(listTracks.length, first + count);
  const rows = listTracks.slice(first, last).map((t) => {
    const ft = altFt(t);
    return `<tr data-icao="${esc(t.icao)}"${t.icao === selected ? ' class="selected"' : ""}>` +
      `<td>${esc(t.callsign ?? "")}</td><td>${esc(t.icao)}</td>` +
      `<td><span class="badge" style="background:${colourOf(t.mode)}">${esc(t.mode)}</span></td>` +
      `<td class="num">${t.on_ground ? "GND" : ft === null ? "-" : Math.round(ft)}</td>` +
      `<td class="num">${fmt(t.ground_speed_mps * KT_PER_MPS, 0)}</td>` +
      `<td class="num">${fmt(t.vertical_rate_mps * FT_PER_M * 60, 0)}</td>` +
      `<td class="num">${fmt(t.pos_sigma_m, 0)}</td><td class="num">${t.messages ?? ""}</td></tr>`;
  });
  const spacer = (n) => (n > 0 ? `<tr class="spacer" style="height:${n * rowH}px"><td colspan="8"></td></tr>` : "");
  $("list-rows").innerHTML = spacer(first) + rows.join("") + spacer(listTracks.length - last);
  if (!rowMeasured) {
    const row = $("list-rows").querySelector("tr:not(.spacer)");
    if (row && row.offsetHeight > 0) {
      rowH = row.offsetHeight;
      rowMeasured = true;
    }
  }
}

/** Marks `a` selected or not: its trail and prediction circles (the canvas draws the ring). */
function highlight(a, on) {
  if (!a) return;
  a.trailLine.setStyle({ weight: on ? 3 : 1.5 });
  for (const c of a.predCircles) {
    (on ? predictionCircles : selectedCircles).removeLayer(c);
    if (a.shown) (on ? selectedCircles : predictionCircles).addLayer(c);
  }
  vectorQueue.add(a);
}

function select(icao, pan) {
  const prev = aircraft.get(selected);
  selected = icao;
  highlight(prev, false);
  const a = aircraft.get(icao);
  if (!a) return;
  highlight(a, true);
  if (pan) map.panTo([a.track.lat, a.track.lon]);
  $("panel").hidden = false;
  renderPanel();
  renderRows();
  aircraftCanvas.redraw();
  queueFrame();
}
$("panel-close").addEventListener("click", () => {
  const prev = aircraft.get(selected);
  selected = null;
  highlight(prev, false);
  $("panel").hidden = true;
  renderRows();
  aircraftCanvas.redraw();
  queueFrame();
});

/** One value of the "every field" table. */
function fieldValue(v) {
  if (v === null || v === undefined) return "-";
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : String(Math.abs(v) >= 1e5 ? v.toFixed(3) : +v.toPrecision(7));
  if (Array.isArray(v)) {
    if (v.length && Array.isArray(v[0])) return v.map((row) => row.map(fieldValue).join("  ")).join("<br>");
    if (v.length && typeof v[0] === "object") return v.map((o) => esc(Object.entries(o).map(([k, x]) => `${k} ${fieldValue(x)}`).join(", "))).join("<br>");
    return esc(v.map(fieldValue).join(", "));
  }
  if (typeof v === "object") return esc(Object.entries(v).map(([k, x]) => `${k} ${fieldValue(x)}`).join(", "));
  return esc(v);
}

let panelRendered = 0;
let panelDirty = false;
function renderPanel() {
  panelRendered = performance.now();
  panelDirty = false;
  const a = aircraft.get(selected);
  if (!a || !a.track) {
    $("panel-body").innerHTML = `<p class="muted">retired (no report for the tracker's retire time)</p>`;
    return;
  }
  const t = a.track;
  $("panel-title").textContent = t.callsign || t.icao;
  const age = fin(stats?.feed_time) && fin(t.last_seen) ? Math.max(0, stats.feed_time - t.last_seen) : null;
  const probs = t.mode_probabilities ?? {};
  const axis = (name, value) => `<span class="axis">${name} <b>${esc(value ?? "-")}</b></span>`;
  const ft = altFt(t);
  $("panel-body").innerHTML =
    `<div class="sub">${esc(t.icao)}${t.squawk ? ` &middot; squawk ${esc(t.squawk)}` : ""}${t.category ? ` &middot; ${esc(t.category)}` : ""} &middot; ${esc(t.filter)}</div>` +
    `<div class="axes"><span class="badge" style="background:${colourOf(t.mode)}">${esc(t.mode)}${t.turn ? " " + esc(t.turn) : ""}</span> ` +
    axis("lateral", t.lateral) + axis("speed", t.speed) + axis("vertical", t.vertical) + `</div>` +
    `<div class="probs">` +
    MODES.map(([m, c]) => {
      const p = fin(probs[m]) ? probs[m] : 0;
      return `<div class="prob"><span class="name">${m}</span><div class="bar"><div style="width:${(p * 100).toFixed(1)}%;background:${c}"></div></div><span class="val">${(p * 100).toFixed(1)} %</span></div>`;
    }).join("") +
    `</div><dl class="facts">` +
    `<dt>altitude</dt><dd>${t.on_ground ? "on ground" : `${ft === null ? "-" : Math.round(ft)} ft (${fmt(t.alt_m, 0)} m)`}${t.baro_alt_ft != null ? `, baro ${t.baro_alt_ft} ft` : ""}</dd>` +
    `<dt>ground speed</dt><dd>${fmt(t.ground_speed_mps * KT_PER_MPS, 0)} kt, track ${fmt(t.track_deg, 1)}&deg;</dd>` +
    `<dt>vertical rate</dt><dd>${fmt(t.vertical_rate_mps * FT_PER_M * 60, 0)} ft/min</dd>` +
    `<dt>position &sigma;</dt><dd>${fmt(t.pos_sigma_m, 1)} m (velocity ${fmt(t.vel_sigma_mps, 2)} m/s)</dd>` +
    `<dt>divergence</dt><dd${t.diverging ? ' class="alert"' : ""}>${t.diverging ? "diverging now" : "not diverging"}; ${t.divergence_events ?? 0} events</dd>` +
    `<dt>messages</dt><dd>${t.messages ?? "-"}; positions ${t.positions_accepted ?? "-"} accepted, ${t.positions_rejected ?? "-"} rejected, ${t.outlier_positions ?? 0} set aside</dd>` +
    `<dt>last heard</dt><dd>${age === null ? "-" : `${age.toFixed(1)} s ago`}</dd>` +
    `</dl><details open><summary>every field</summary><table class="fields">` +
    Object.entries(t).map(([k, v]) => `<tr><td>${esc(k)}</td><td>${fieldValue(v)}</td></tr>`).join("") +
    `</table></details>`;
}

// ---------------------------------------------------------------------------------------
// Counters.

let stats = null;
let lastRate = null;
function renderStats() {
  if (!stats) return;
  $("c-aircraft").textContent = String(aircraft.size);
  $("c-aircraft").title = `tracks_active ${stats.tracks_active}`;
  const now = performance.now();
  if (lastRate && fin(stats.frames) && now > lastRate.at) {
    const rate = ((stats.frames - lastRate.frames) * 1000) / (now - lastRate.at);
    if (rate >= 0) $("c-rate").textContent = rate >= 100 ? Math.round(rate).toLocaleString("en") : rate.toFixed(1);
  }
  if (fin(stats.frames)) lastRate = { frames: stats.frames, at: now };
  const feeds = Array.isArray(stats.feeds) ? stats.feeds : [];
  const feed = $("c-feed");
  if (feeds.length) {
    const up = feeds.filter((f) => f.connected && !f.silent).length;
    feed.textContent = `${up}/${feeds.length} up`;
    feed.title = feeds.map((f) => `${f.name}: ${f.connected ? (f.silent ? "silent" : "connected") : "down"}`).join("\n");
    feed.classList.toggle("bad", up < feeds.length);
  } else {
    feed.textContent = stats.replay_finished ? "replay ended" : "replay";
    feed.classList.remove("bad");
  }
  const lag = $("c-lag");
  lag.textContent = fin(stats.ingest_lag_s) ? `${stats.ingest_lag_s.toFixed(2)} s` : "-";
  lag.classList.toggle("bad", !!stats.lagging);
  if (fin(stats.feed_time) && stats.feed_time > 1e8) {
    $("c-time").textContent = new Date(stats.feed_time * 1000).toISOString().slice(11, 19);
  } else if (fin(stats.feed_time)) {
    $("c-time").textContent = `${stats.feed_time.toFixed(0)} s`;
  }
}

// ---------------------------------------------------------------------------------------
// The frame loop: everything the events changed, drawn once.

let frameQueued = false;
let lastVectorPass = 0;
function queueFrame() {
  if (!frameQueued) {
    frameQueued = true;
    requestAnimationFrame(frame);
  }
}

function frame() {
  frameQueued = false;
  const start = performance.now();
  let changed = false;
  for (const icao of retired) {
    const a = aircraft.get(icao);
    if (a) {
      a.remove();
      aircraft.delete(icao);
      changed = true;
      if (icao === selected) panelDirty = true;
    }
  }
  retired.clear();
  for (const [icao, t] of pending) {
    let a = aircraft.get(icao);
    if (!a) {
      a = new Aircraft(t);
      aircraft.set(icao, a);
      requestHistory(icao);
    }
    a.update(t);
    if (icao === selected) panelDirty = true;
    changed = true;
  }
  pending.clear();
  if (fitDue) fitOnce();
  if (changed) {
    listDirty = true;
    aircraftCanvas.redraw(true);
  }
  // Vectors, a pass every VECTOR_PERIOD_MS, oldest request first, for as long as the budget
  // lasts; those far out of view wait for the view to come to them (moveend queues every
  // aircraft again).
  if (vectorQueue.size && !moving && start - lastVectorPass >= VECTOR_PERIOD_MS) {
    lastVectorPass = start;
    const bounds = map.getBounds().pad(0.5);
    const view = { metresPerPixel: EARTH_CIRCUMFERENCE_M / 2 ** (map.getZoom() + 8) };
    for (const a of vectorQueue) {
      if (performance.now() - start > VECTOR_BUDGET_MS) break;
      vectorQueue.delete(a);
      if (a.track && (a.icao === selected || bounds.contains([a.track.lat, a.track.lon]))) a.drawVectors(view);
    }
  }
  const now = performance.now();
  if (panelDirty && now - panelRendered >= PANEL_REFRESH_MS) renderPanel();
  if (listDirty && now - listRendered >= LIST_REFRESH_MS) renderList();
  $("c-aircraft").textContent = String(aircraft.size);
  // Work left (vectors, the throttled list or panel): come back when it is due.
  const due = [];
  if (panelDirty) due.push(panelRendered + PANEL_REFRESH_MS);
  if (listDirty) due.push(listRendered + LIST_REFRESH_MS);
  if (vectorQueue.size && !moving) due.push(lastVectorPass + VECTOR_PERIOD_MS);
  if (due.length && !laterTimer) {
    laterTimer = setTimeout(() => {
      laterTimer = null;
      queueFrame();
    }, Math.max(0, Math.min(...due) - performance.now()));
  }
}
let laterTimer = null;

/** Fits the view to the aircraft once, when the first state is in (until then the view
 * holds the receiver's range rings, or the world). */
function fitOnce() {
  fitDue = false;
  if (fitted || aircraft.size === 0) return;
  const b = L.latLngBounds([...aircraft.values()].map((a) => [a.track.lat, a.track.lon]));
  if (b.isValid()) map.fitBounds(b.pad(0.05), { maxZoom: 10 });
  fitted = true;
}

// ---------------------------------------------------------------------------------------
// The event stream.

/** Connection number; each aircraft remembers the last one that told of it. */
let epoch = 0;
const heardIn = new Map();
let statsSinceOpen = 0;
let reconnectMs = RECONNECT_MIN_MS;
let source = null;
/** Events received, by type (for the curious and the tests). */
const counts = { track: 0, retire: 0, stats: 0 };

function setStream(state) {
  const el = $("c-stream");
  el.textContent = state;
  el.className = `stream ${state === "live" ? "live" : "down"}`;
}

function parse(ev) {
  try {
    return JSON.parse(ev.data);
  } catch {
    return null;
  }
}

function connect() {
  source = new EventSource("api/v1/stream");
  source.addEventListener("open", () => {
    epoch++;
    statsSinceOpen = 0;
    reconnectMs = RECONNECT_MIN_MS;
    setStream("live");
  });
  source.addEventListener("track", (ev) => {
    counts.track++;
    const t = parse(ev);
    if (!t || typeof t.icao !== "string" || !fin(t.lat) || !fin(t.lon)) return;
    pending.set(t.icao, t);
    retired.delete(t.icao);
    heardIn.set(t.icao, epoch);
    queueFrame();
  });
  source.addEventListener("retire", (ev) => {
    counts.retire++;
    const r = parse(ev);
    if (!r || typeof r.icao !== "string") return;
    pending.delete(r.icao);
    heardIn.delete(r.icao);
    retired.add(r.icao);
    queueFrame();
  });
  source.addEventListener("stats", (ev) => {
    counts.stats++;
    const s = parse(ev);
    if (!s) return;
    stats = s;
    statsSinceOpen++;
    // After a reconnection the server sent every current track first: by the second stats
    // event (a second later), aircraft it did not mention were retired while we were away.
    if (statsSinceOpen === 2 && epoch > 1) {
      for (const icao of aircraft.keys()) {
        if ((heardIn.get(icao) ?? 0) < epoch && !pending.has(icao)) {
          retired.add(icao);
          heardIn.delete(icao);
        }
      }
      queueFrame();
    }
    if (!fitted) {
      fitDue = true;
      queueFrame();
    }
    renderStats();
  });
  source.addEventListener("error", () => {
    if (source.readyState === EventSource.CLOSED) {
      // The browser gave up (an HTTP error, a wrong type): retry with a growing delay.
      setStream(`reconnecting in ${Math.round(reconnectMs / 1000)} s`);
      source.close();
      setTimeout(connect, reconnectMs);
      reconnectMs = Math.min(reconnectMs * 2, RECONNECT_MAX_MS);
    } else {
      setStream("reconnecting");
    }
  });
}
connect();
// (Registered last: the map fires these for its first layers when it gets its view.)
map.on("overlayadd overlayremove", (e) => {
  if (e.layer === labels) aircraftCanvas.redraw();
  // Vectors of layers that were off were not refreshed: bring them up to date.
  if (e.type === "overlayadd") queueAllVectors();
});
map.on("zoomend moveend", queueAllVectors);

// For tests and the curious: the page's state, read-only.
window.adsbMap = {
  map,
  /** The aircraft on the map (those the filters let through), in or out of view. */
  icaos: () => [...aircraft.values()].filter((a) => a.shown).map((a) => a.icao),
  track: (icao) => aircraft.get(icao)?.track ?? null,
  /** icao -> [x, y] of each icon in the last drawing, in the map container's pixels. */
  drawn: () => Object.fromEntries(aircraftCanvas.drawn),
  /** Events received but not yet drawn (a frame or a throttled canvas redraw is due): while
   * true, `drawn` may lag `icaos` by the aircraft that arrived since the last drawing. */
  drawPending: () =>
    frameQueued || pending.size > 0 || aircraftCanvas._queued || aircraftCanvas._timer !== null,
  selected: () => selected,
  /** Fitted to the aircraft and not moving: what a test waits for before it measures. */
  settled: () => fitted && !moving,
  /** Stream connections opened so far (1 until a reconnection). */
  connections: () => epoch,
  events: () => ({ ...counts }),
  /** Vector refreshes waiting. */
  backlog: () => vectorQueue.size,
};
