/* geofuse's browser map (app/share/web.py): the aircraft, its track, the footprint, the point
 * of interest, the frame's picture and the marks, kept up to date from the server's event
 * stream. Read-only. Coordinates arrive as the server shares them: GeoJSON order (longitude,
 * latitude, degrees; heights in metres above the WGS84 ellipsoid), and are drawn unrounded.
 *
 * window.geofuseMap holds what is shown (the last frame as it arrived, the track, the marks)
 * and what was drawn from it, for the tests and the benchmark to read. */
(function () {
  "use strict";

  const token = new URLSearchParams(window.location.search).get("token") || "";
  const auth = "token=" + encodeURIComponent(token);
  const ORANGE = "#ff6d00";
  const FRAME_STALE_MS = 10000;
  const APPLIED_KEPT = 500;

  const mapDiv = document.getElementById("map");
  const map = L.map(mapDiv, { worldCopyJump: true, zoomSnap: 0.25 }).setView([20, 0], 2);
  L.control.scale({ imperial: false, maxWidth: 160 }).addTo(map);

  const track = L.polyline([], { color: "#1565c0", weight: 3, opacity: 0.85 }).addTo(map);
  const footprint = L.geoJSON(null, {
    style: { color: ORANGE, weight: 2, fillColor: ORANGE, fillOpacity: 0.22 },
  }).addTo(map);
  const axis = L.polyline([], { color: ORANGE, weight: 1.5, dashArray: "5 5", opacity: 0.9 });
  const centre = L.circleMarker([0, 0], {
    radius: 6, color: "#ffffff", weight: 2, fillColor: "#d50000", fillOpacity: 1,
  });
  const marks = L.geoJSON(null, {
    style: { color: "#6a1b9a", weight: 3, fillOpacity: 0.15 },
    pointToLayer: (feature, latlng) => L.circleMarker(latlng, {
      radius: 7, color: "#ffffff", weight: 2, fillColor: "#6a1b9a", fillOpacity: 1,
    }),
    onEachFeature: (feature, layer) => {
      const label = (feature.properties && feature.properties.label) || "mark";
      layer.bindTooltip(label, { permanent: true, direction: "right", offset: [8, 0] });
    },
  }).addTo(map);
  const arrow =
    '<svg viewBox="0 0 30 30"><path d="M15 2 L25 27 L15 21 L5 27 Z" fill="#1565c0" ' +
    'stroke="#ffffff" stroke-width="2" stroke-linejoin="round"/></svg>';
  const aircraft = L.marker([0, 0], {
    icon: L.divIcon({ className: "aircraft", html: arrow, iconSize: [30, 30], iconAnchor: [15, 15] }),
    interactive: false, keyboard: false, zIndexOffset: 1000,
  });

  const shown = {
    connected: false,
    map: null, // the server's map settings (imagery or none)
    frame: null, // the last frame as it arrived (SharedFrame.as_dict)
    seq: 0,
    track: [], // the sensor's [lon, lat, h], as shared
    trackEpoch: -1,
    marks: null, // the marks' FeatureCollection as it arrived
    updates: 0, // frames applied
    applied: [], // [frame index, Date.now() ms once drawn], the last APPLIED_KEPT
    lastFrameMs: null,
  };
  window.geofuseMap = shown;

  function lonLat(latlngs) {
    // Leaflet's nested LatLng arrays as nested [lon, lat] arrays
    return Array.isArray(latlngs) ? latlngs.map(lonLat) : [latlngs.lng, latlngs.lat];
  }
  shown.drawnFootprint = () => footprint.getLayers().map((layer) => lonLat(layer.getLatLngs()));
  shown.drawnTrack = () => lonLat(track.getLatLngs());
  shown.drawnAircraft = () => (map.hasLayer(aircraft) ? lonLat(aircraft.getLatLng()) : null);
  shown.drawnCentre = () => (map.hasLayer(centre) ? lonLat(centre.getLatLng()) : null);
  shown.drawnMarks = () =>
    marks.getLayers().map((layer) => ({
      label: layer.getTooltip() ? layer.getTooltip().getContent() : null,
      at: lonLat(layer.getLatLng ? layer.getLatLng() : layer.getLatLngs()),
    }));

  // -- the background: imagery through the server, or a plain grid --------------------------------

  const grid = L.layerGroup();
  const GRID_STEPS = [
    30, 10, 5, 2, 1, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001, 0.0005, 0.0002,
    0.0001, 0.00005, 0.00002, 0.00001,
  ];

  function drawGrid() {
    grid.clearLayers();
    const b = map.getBounds();
    const across = Math.max(b.getEast() - b.getWest(), 1e-9);
    let step = GRID_STEPS[GRID_STEPS.length - 1];
    for (const s of GRID_STEPS) {
      if (across / s >= 4) { step = s; break; }
    }
    const digits = Math.max(0, Math.ceil(-Math.log10(step)));
    const style = { color: "#9aa3ad", weight: 1, opacity: 0.6, interactive: false };
    const south = Math.max(b.getSouth(), -85), north = Math.min(b.getNorth(), 85);
    for (let lon = Math.ceil(b.getWest() / step) * step; lon <= b.getEast(); lon += step) {
      grid.addLayer(L.polyline([[south, lon], [north, lon]], style));
      grid.addLayer(L.marker([north, lon], {
        icon: L.divIcon({ className: "grid-label", html: lon.toFixed(digits) + "°", iconAnchor: [-2, -2] }),
        interactive: false, keyboard: false,
      }));
    }
    for (let lat = Math.ceil(south / step) * step; lat <= north; lat += step) {
      grid.addLayer(L.polyline([[lat, b.getWest()], [lat, b.getEast()]], style));
      grid.addLayer(L.marker([lat, b.getWest()], {
        icon: L.divIcon({ className: "grid-label", html: lat.toFixed(digits) + "°", iconAnchor: [-2, 12] }),
        interactive: false, keyboard: false,
      }));
    }
    document.getElementById("background").textContent =
      "No imagery configured: a plain background with a grid every " + step + "° and a scale " +
      "(imagery comes from a world's tile source: geofuse --world NAME or --imagery SRC).";
  }

  function setUpBackground(settings) {
    shown.map = settings;
    const note = document.getElementById("background");
    if (settings.imagery) {
      L.tileLayer("tiles/{z}/{x}/{y}?" + auth, {
        maxNativeZoom: settings.imagery.max_zoom,
        maxZoom: 22,
        attribution: settings.imagery.attribution,
      }).addTo(map);
      note.textContent = "Imagery: the world source geofuse was given, through geofuse" +
        (settings.imagery.attribution ? " (" + settings.imagery.attribution + ")" : "") + ".";
    } else {
      mapDiv.classList.add("plain");
      grid.addTo(map);
      map.on("moveend", drawGrid);
      drawGrid();
    }
  }

  // -- what is shared -----------------------------------------------------------------------------

  function fixed(v, n) {
    return v === null || v === undefined ? "n/a" : Number(v).toFixed(n);
  }

  function describe(f) {
    const when = f.utc_s !== null ? new Date(f.utc_s * 1000).toISOString().replace("T", " ").replace("Z", " UTC")
      : "media " + fixed(f.media_s, 2) + " s";
    const rows = [
      ["time", when],
      ["clip", f.clip + ", frame " + f.index],
      ["camera", fixed(f.sensor[0], 6) + ", " + fixed(f.sensor[1], 6)],
      ["height", fixed(f.sensor[2], 1) + " m (ellipsoid), " + fixed(f.sensor_msl_m, 1) + " m MSL"],
      ["heading", fixed(f.heading_deg, 1) + "°, pitch " + fixed(f.pitch_deg, 1) + "°, roll " + fixed(f.roll_deg, 1) + "°"],
      ["field of view", fixed(f.hfov_deg, 1) + "° x " + fixed(f.vfov_deg, 1) + "°"],
      ["looking at", f.centre ? fixed(f.centre[0], 6) + ", " + fixed(f.centre[1], 6) + " (" + fixed(f.slant_m, 0) + " m away)" : "nothing within range"],
      ["pose", f.source + (f.gnss ? ", GNSS " + f.gnss : "")],
    ];
    const body = document.createElement("tbody");
    for (const [k, v] of rows) {
      const tr = body.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = v;
    }
    const table = document.getElementById("info");
    table.replaceChild(body, table.tBodies[0]);
  }

  function setTrack(start, points, epoch) {
    const appended = epoch === shown.trackEpoch && start === shown.track.length;
    shown.track.length = start;
    for (const p of points) shown.track.push(p);
    shown.trackEpoch = epoch;
    if (appended) {
      for (const p of points) track.addLatLng([p[1], p[0]]);
    } else {
      track.setLatLngs(shown.track.map((p) => [p[1], p[0]]));
    }
  }

  function follow(first) {
    const aim = L.latLngBounds([aircraft.getLatLng()]);
    if (footprint.getLayers().length) aim.extend(footprint.getBounds());
    if (first) {
      map.fitBounds(aim.pad(0.3), { maxZoom: 19 });
    } else if (document.getElementById("follow").checked && !map.getBounds().pad(-0.1).contains(aim)) {
      map.fitBounds(aim.pad(0.3), { maxZoom: map.getZoom() > 3 ? map.getZoom() : 19 });
    }
  }

  function applyFrame(f, seq) {
    const first = shown.frame === null;
    shown.frame = f;
    shown.seq = seq;
    footprint.clearLayers();
    if (f.footprint) footprint.addData(f.footprint);
    aircraft.setLatLng([f.sensor[0], f.sensor[1]]).addTo(map);
    const svg = aircraft.getElement() && aircraft.getElement().querySelector("svg");
    if (svg) svg.style.transform = "rotate(" + f.heading_deg + "deg)";
    if (f.centre) {
      centre.setLatLng([f.centre[0], f.centre[1]]).addTo(map);
      axis.setLatLngs([[f.sensor[0], f.sensor[1]], [f.centre[0], f.centre[1]]]).addTo(map);
    } else {
      centre.remove();
      axis.remove();
    }
    const thumb = document.getElementById("thumb");
    if (f.thumbnail) {
      thumb.src = "thumbnail.jpg?" + auth + "&seq=" + seq;
      thumb.alt = "frame " + f.index;
      thumb.hidden = false;
    }
    describe(f);
    follow(first);
    shown.updates += 1;
    shown.lastFrameMs = Date.now();
    shown.applied.push([f.index, shown.lastFrameMs]);
    if (shown.applied.length > APPLIED_KEPT) shown.applied.splice(0, shown.applied.length - APPLIED_KEPT);
  }

  function applyMarks(fc) {
    shown.marks = fc;
    marks.clearLayers();
    if (fc) marks.addData(fc);
  }

  function applyState(s) {
    if (shown.map === null) setUpBackground(s.map);
    setTrack(0, s.track, s.track_epoch);
    applyMarks(s.marks);
    if (s.frame) applyFrame(s.frame, s.seq);
  }

  // -- the event stream ---------------------------------------------------------------------------

  const status = document.getElementById("status");
  function say(text, kind) {
    status.textContent = text;
    status.className = kind;
  }

  const events = new EventSource("events?" + auth);
  events.addEventListener("state", (e) => applyState(JSON.parse(e.data)));
  events.addEventListener("frame", (e) => {
    const d = JSON.parse(e.data);
    setTrack(d.track_start, d.track, d.track_epoch);
    applyFrame(d.frame, d.seq);
  });
  events.addEventListener("marks", (e) => applyMarks(JSON.parse(e.data).marks));
  events.onopen = () => {
    shown.connected = true;
    say("live", "live");
  };
  events.onerror = () => {
    shown.connected = false;
    say("reconnecting", "lost");
  };
  window.setInterval(() => {
    if (!shown.connected) return;
    if (shown.lastFrameMs === null) say("live, no frame yet", "waiting");
    else if (Date.now() - shown.lastFrameMs > FRAME_STALE_MS) {
      say("no frame for " + Math.round((Date.now() - shown.lastFrameMs) / 1000) + " s", "waiting");
    } else say("live", "live");
  }, 1000);
  map.on("dragstart", () => { document.getElementById("follow").checked = false; });
})();
