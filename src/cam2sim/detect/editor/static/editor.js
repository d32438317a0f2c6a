// cam2sim refine: the parked-vehicle editor. Plain JavaScript, no build step, no network beyond
// the local server. World coordinates are metres (x east, y north); the canvas shows north up.
// window.editor is a small hook for tests and the console (see the end of this file).
(function () {
  "use strict";

  const ROTATE_STEP = (5 * Math.PI) / 180;
  const HANDLE_PX = 22; // rotation handle distance beyond the box end, screen pixels
  const HANDLE_R_PX = 7;
  const LANE_FILL = {
    drivable: "rgba(125, 135, 150, 0.32)",
    parking: "rgba(70, 130, 220, 0.38)",
    sidewalk: "rgba(200, 170, 110, 0.32)",
    shoulder: "rgba(110, 160, 110, 0.25)",
    biking: "rgba(110, 160, 110, 0.25)",
    other: "rgba(110, 160, 110, 0.2)",
  };

  const $ = (id) => document.getElementById(id);
  const canvas = $("map");
  const ctx = canvas.getContext("2d");
  const inputs = {
    x: $("in-x"), y: $("in-y"), yaw: $("in-yaw"),
    length: $("in-length"), width: $("in-width"), height: $("in-height"),
  };

  const state = {
    scene: null,
    vehicles: [],
    selected: null,
    history: [],
    savedJson: "[]",
    revision: "none",
    view: { cx: 0, cy: 0, scale: 10 },
    mode: "select",
    drag: null,
    bevImage: null,
    layers: { bev: true, lanes: true, route: true, labels: true },
    tempCounter: 0,
    saving: false,
  };

  // -- geometry ----------------------------------------------------------------------------
  function wrapAngle(a) {
    return Math.atan2(Math.sin(a), Math.cos(a));
  }

  function round(v, digits) {
    const f = 10 ** digits;
    return Math.round(v * f) / f;
  }

  function canvasSize() {
    return { w: canvas.clientWidth, h: canvas.clientHeight };
  }

  // World metres to canvas CSS pixels (origin: the canvas's top-left corner).
  function worldToCanvas(x, y) {
    const { w, h } = canvasSize();
    const v = state.view;
    return { x: (x - v.cx) * v.scale + w / 2, y: h / 2 - (y - v.cy) * v.scale };
  }

  function canvasToWorld(px, py) {
    const { w, h } = canvasSize();
    const v = state.view;
    return { x: (px - w / 2) / v.scale + v.cx, y: (h / 2 - py) / v.scale + v.cy };
  }

  function eventWorld(ev) {
    const r = canvas.getBoundingClientRect();
    return canvasToWorld(ev.clientX - r.left, ev.clientY - r.top);
  }

  function axes(v) {
    const c = Math.cos(v.yaw), s = Math.sin(v.yaw);
    return { u: [c, s], n: [-s, c] };
  }

  function corners(v) {
    const { u, n } = axes(v);
    const hl = v.size[0] / 2, hw = v.size[1] / 2;
    const [x, y] = v.position;
    return [[1, 1], [-1, 1], [-1, -1], [1, -1]].map(([a, b]) => [
      x + a * hl * u[0] + b * hw * n[0],
      y + a * hl * u[1] + b * hw * n[1],
    ]);
  }

  function handleWorld(v) {
    const { u } = axes(v);
    const d = v.size[0] / 2 + HANDLE_PX / state.view.scale;
    return { x: v.position[0] + d * u[0], y: v.position[1] + d * u[1] };
  }

  function contains(v, p, tolerance) {
    const { u, n } = axes(v);
    const dx = p.x - v.position[0], dy = p.y - v.position[1];
    const a = dx * u[0] + dy * u[1], b = dx * n[0] + dy * n[1];
    return Math.abs(a) <= v.size[0] / 2 + tolerance && Math.abs(b) <= v.size[1] / 2 + tolerance;
  }

  // Nearest route vertex: its index, heading along the route, and position.
  function nearestRoute(x, y) {
    const route = state.scene ? state.scene.route : [];
    if (route.length < 2) return null;
    let best = 0, bestD = Infinity;
    for (let i = 0; i < route.length; i++) {
      const dx = route[i][0] - x, dy = route[i][1] - y;
      const d = dx * dx + dy * dy;
      if (d < bestD) { bestD = d; best = i; }
    }
    const a = route[Math.max(0, best - 1)], b = route[Math.min(route.length - 1, best + 1)];
    return { index: best, heading: Math.atan2(b[1] - a[1], b[0] - a[0]), point: route[best] };
  }

  // The server recomputes these on save; the page shows them for the current edits.
  function relateToRoute(v) {
    const near = nearestRoute(v.position[0], v.position[1]);
    if (!near) return;
    const h = near.heading;
    const dx = v.position[0] - near.point[0], dy = v.position[1] - near.point[1];
    v.side = Math.cos(h) * dy - Math.sin(h) * dx > 0 ? "left" : "right";
    let diff = Math.abs(wrapAngle(v.yaw - h));
    diff = Math.min(diff, Math.PI - diff);
    v.orientation = diff < Math.PI / 4 ? "parallel" : "perpendicular";
  }

  // -- state -------------------------------------------------------------------------------
  function selectedVehicle() {
    return state.vehicles.find((v) => v.id === state.selected) || null;
  }

  function snapshot() {
    return { vehicles: JSON.stringify(state.vehicles), selected: state.selected };
  }

  function pushHistory(snap) {
    state.history.push(snap || snapshot());
    refresh();
  }

  function undo() {
    const snap = state.history.pop();
    if (!snap) return;
    state.vehicles = JSON.parse(snap.vehicles);
    state.selected = state.vehicles.some((v) => v.id === snap.selected) ? snap.selected : null;
    setStatus("undone", "idle");
    refresh();
  }

  function markEdited(v) {
    v.edited = true;
    relateToRoute(v);
  }

  function isDirty() {
    return JSON.stringify(state.vehicles) !== state.savedJson;
  }

  function setStatus(text, kind) {
    const el = $("status");
    el.textContent = text;
    el.dataset.state = kind;
  }

  function setMode(mode) {
    state.mode = mode;
    $("btn-insert").classList.toggle("active", mode === "insert");
    canvas.classList.toggle("insert", mode === "insert");
    $("mode-hint").hidden = mode !== "insert";
  }

  function rotateSelected(delta) {
    const v = selectedVehicle();
    if (!v) return;
    pushHistory();
    v.yaw = wrapAngle(v.yaw + delta);
    markEdited(v);
    refresh();
  }

  function deleteSelected() {
    const v = selectedVehicle();
    if (!v) return;
    pushHistory();
    state.vehicles = state.vehicles.filter((o) => o !== v);
    state.selected = null;
    setStatus(`deleted ${v.id}`, "idle");
    refresh();
  }

  function newId() {
    const taken = new Set(state.vehicles.map((v) => v.id));
    let id;
    do { id = `new_${++state.tempCounter}`; } while (taken.has(id));
    return id;
  }

  function insertAt(p) {
    const near = nearestRoute(p.x, p.y);
    let z = near ? near.point[2] : 0;
    let bestD = 30 * 30;
    for (const o of state.vehicles) {
      const d = (o.position[0] - p.x) ** 2 + (o.position[1] - p.y) ** 2;
      if (d < bestD) { bestD = d; z = o.position[2]; }
    }
    const size = (state.scene && state.scene.defaults.size) || [4.5, 1.8, 1.5];
    const v = {
      id: newId(),
      position: [round(p.x, 3), round(p.y, 3), z],
      yaw: near ? wrapAngle(near.heading) : 0,
      size: size.slice(),
      confidence: 1.0,
      hits: 0,
      side: "right",
      orientation: "parallel",
      source: "manual",
      edited: true,
    };
    relateToRoute(v);
    pushHistory();
    state.vehicles.push(v);
    state.selected = v.id;
    setMode("select");
    setStatus(`inserted ${v.id}`, "idle");
    refresh();
  }

  // -- saving ------------------------------------------------------------------------------
  async function save() {
    if (state.saving) return;
    state.saving = true;
    setStatus("saving…", "saving");
    try {
      const resp = await fetch("/api/save", {
        method: "POST",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ vehicles: state.vehicles, revision: state.revision }),
      });
      let body = null;
      try { body = await resp.json(); } catch (e) { body = null; }
      if (!resp.ok) {
        const why = body && body.error ? body.error : `HTTP ${resp.status}`;
        setStatus(`save failed: ${why}`, "error");
        return;
      }
      const idMap = body.id_map || {};
      const remap = (v) => { if (idMap[v.id]) v.id = idMap[v.id]; return v; };
      state.history = state.history.map((snap) => ({
        vehicles: JSON.stringify(JSON.parse(snap.vehicles).map(remap)),
        selected: idMap[snap.selected] || snap.selected,
      }));
      state.selected = idMap[state.selected] || state.selected;
      state.vehicles = body.vehicles;
      state.savedJson = JSON.stringify(state.vehicles);
      state.revision = body.revision;
      const kept = body.history ? `; previous version in ${body.history}` : "";
      setStatus(`saved ${body.saved} vehicles${kept}`, "saved");
    } catch (err) {
      setStatus(`save failed: ${err}`, "error");
    } finally {
      state.saving = false;
      refresh();
    }
  }

  // -- view --------------------------------------------------------------------------------
  function fit() {
    const pts = [];
    if (state.scene) for (const p of state.scene.route) pts.push(p);
    for (const v of state.vehicles) pts.push(v.position);
    const { w, h } = canvasSize();
    if (!pts.length || !w || !h) return;
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (const p of pts) {
      x0 = Math.min(x0, p[0]); x1 = Math.max(x1, p[0]);
      y0 = Math.min(y0, p[1]); y1 = Math.max(y1, p[1]);
    }
    const pad = 8;
    state.view.cx = (x0 + x1) / 2;
    state.view.cy = (y0 + y1) / 2;
    state.view.scale = Math.min(w / (x1 - x0 + 2 * pad), h / (y1 - y0 + 2 * pad));
    draw();
  }

  function resize() {
    const dpr = window.devicePixelRatio || 1;
    const { w, h } = canvasSize();
    canvas.width = Math.max(1, Math.round(w * dpr));
    canvas.height = Math.max(1, Math.round(h * dpr));
    draw();
  }

  // -- drawing -----------------------------------------------------------------------------
  function pathPolygon(points) {
    ctx.beginPath();
    points.forEach((p, i) => {
      const s = worldToCanvas(p[0], p[1]);
      if (i === 0) ctx.moveTo(s.x, s.y); else ctx.lineTo(s.x, s.y);
    });
    ctx.closePath();
  }

  function drawLanes() {
    for (const lane of state.scene.lanes) {
      ctx.fillStyle = LANE_FILL[lane.kind] || LANE_FILL.other;
      for (const ring of lane.rings) {
        pathPolygon(ring);
        ctx.fill();
        ctx.strokeStyle = "rgba(255, 255, 255, 0.12)";
        ctx.lineWidth = 1;
        ctx.stroke();
      }
    }
  }

  function drawBev() {
    const b = state.scene.bev;
    const a = worldToCanvas(b.x_min, b.y_max), c = worldToCanvas(b.x_max, b.y_min);
    ctx.imageSmoothingEnabled = state.view.scale * b.resolution_m < 2;
    ctx.drawImage(state.bevImage, a.x, a.y, c.x - a.x, c.y - a.y);
    ctx.imageSmoothingEnabled = true;
  }

  function drawRoute() {
    const route = state.scene.route;
    if (route.length < 2) return;
    ctx.beginPath();
    route.forEach((p, i) => {
      const s = worldToCanvas(p[0], p[1]);
      if (i === 0) ctx.moveTo(s.x, s.y); else ctx.lineTo(s.x, s.y);
    });
    ctx.strokeStyle = "#4fc3f7";
    ctx.lineWidth = 2;
    ctx.stroke();
    const s = worldToCanvas(route[0][0], route[0][1]);
    ctx.fillStyle = "#4fc3f7";
    ctx.beginPath();
    ctx.arc(s.x, s.y, 4, 0, 2 * Math.PI);
    ctx.fill();
  }

  function drawVehicle(v) {
    const selected = v.id === state.selected;
    const colour = v.edited ? "129, 199, 132" : "255, 183, 77";
    pathPolygon(corners(v));
    ctx.fillStyle = `rgba(${colour}, ${selected ? 0.55 : 0.35})`;
    ctx.fill();
    ctx.strokeStyle = selected ? "#ffffff" : `rgb(${colour})`;
    ctx.lineWidth = selected ? 2.5 : 1.5;
    ctx.stroke();
    // the length axis (a parked car has no front the detectors can tell)
    const { u } = axes(v);
    const hl = v.size[0] / 2;
    const a = worldToCanvas(v.position[0] - hl * u[0], v.position[1] - hl * u[1]);
    const b = worldToCanvas(v.position[0] + hl * u[0], v.position[1] + hl * u[1]);
    ctx.beginPath();
    ctx.moveTo(a.x, a.y);
    ctx.lineTo(b.x, b.y);
    ctx.lineWidth = 1;
    ctx.stroke();
    if (selected) {
      const hw = handleWorld(v);
      const h = worldToCanvas(hw.x, hw.y);
      ctx.beginPath();
      ctx.moveTo(b.x, b.y);
      ctx.lineTo(h.x, h.y);
      ctx.strokeStyle = "#ffffff";
      ctx.stroke();
      ctx.beginPath();
      ctx.arc(h.x, h.y, HANDLE_R_PX, 0, 2 * Math.PI);
      ctx.fillStyle = "#2f6fb3";
      ctx.fill();
      ctx.stroke();
    }
    if (state.layers.labels && state.view.scale > 3) {
      const c = worldToCanvas(v.position[0], v.position[1]);
      ctx.font = "11px system-ui, sans-serif";
      ctx.textAlign = "center";
      ctx.textBaseline = "middle";
      ctx.lineWidth = 3;
      ctx.strokeStyle = "rgba(0, 0, 0, 0.8)";
      ctx.strokeText(v.id, c.x, c.y);
      ctx.fillStyle = "#ffffff";
      ctx.fillText(v.id, c.x, c.y);
    }
  }

  function drawScaleBar() {
    const { h } = canvasSize();
    const target = 100 / state.view.scale;
    const step = 10 ** Math.floor(Math.log10(target));
    const metres = [1, 2, 5, 10].map((m) => m * step).filter((m) => m <= target).pop() || step;
    const px = metres * state.view.scale;
    ctx.strokeStyle = "#e6e6e6";
    ctx.fillStyle = "#e6e6e6";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(12, h - 14);
    ctx.lineTo(12 + px, h - 14);
    ctx.stroke();
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "left";
    ctx.textBaseline = "bottom";
    ctx.fillText(`${metres} m`, 12, h - 18);
  }

  function draw() {
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const { w, h } = canvasSize();
    ctx.fillStyle = "#1b1e23";
    ctx.fillRect(0, 0, w, h);
    if (!state.scene) return;
    if (state.layers.lanes) drawLanes();
    if (state.layers.bev && state.bevImage) drawBev();
    if (state.layers.route) drawRoute();
    for (const v of state.vehicles) if (v.id !== state.selected) drawVehicle(v);
    const sel = selectedVehicle();
    if (sel) drawVehicle(sel);
    drawScaleBar();
  }

  // -- panel -------------------------------------------------------------------------------
  function updatePanel() {
    const v = selectedVehicle();
    $("sel-id").textContent = v ? v.id : "none";
    for (const el of Object.values(inputs)) el.disabled = !v;
    for (const id of ["btn-delete", "btn-rotate-left", "btn-rotate-right"]) $(id).disabled = !v;
    $("btn-undo").disabled = state.history.length === 0;
    const info = $("sel-info");
    info.replaceChildren();
    if (v) {
      const values = {
        x: v.position[0].toFixed(2), y: v.position[1].toFixed(2),
        yaw: ((v.yaw * 180) / Math.PI).toFixed(1),
        length: v.size[0].toFixed(2), width: v.size[1].toFixed(2), height: v.size[2].toFixed(2),
      };
      for (const [k, el] of Object.entries(inputs)) {
        if (document.activeElement !== el) el.value = values[k];
      }
      const rows = [
        ["side", v.side], ["orientation", v.orientation], ["source", v.source],
        ["confidence", Number(v.confidence).toFixed(2)], ["hits", v.hits],
        ["edited", v.edited ? "yes" : "no"],
      ];
      for (const [k, val] of rows) {
        const dt = document.createElement("dt");
        dt.textContent = k;
        const dd = document.createElement("dd");
        dd.textContent = String(val);
        dd.dataset.testid = `info-${k}`;
        info.append(dt, dd);
      }
    } else {
      for (const el of Object.values(inputs)) el.value = "";
    }
    $("vehicle-count").textContent = String(state.vehicles.length);
    $("dirty").hidden = !isDirty();
  }

  function refresh() {
    updatePanel();
    draw();
  }

  function applyInput(key) {
    const v = selectedVehicle();
    if (!v) return;
    const value = Number(inputs[key].value);
    const positive = ["length", "width", "height"].includes(key);
    if (!Number.isFinite(value) || (positive && (value <= 0 || value > 30))) {
      setStatus(`${key} must be a number${positive ? " in (0, 30] m" : ""}`, "error");
      updatePanel();
      return;
    }
    pushHistory();
    if (key === "x") v.position[0] = value;
    else if (key === "y") v.position[1] = value;
    else if (key === "yaw") v.yaw = wrapAngle((value * Math.PI) / 180);
    else v.size[{ length: 0, width: 1, height: 2 }[key]] = value;
    markEdited(v);
    refresh();
  }

  // -- pointer and keys --------------------------------------------------------------------
  function hitTest(p) {
    const sel = selectedVehicle();
    if (sel) {
      const hw = handleWorld(sel);
      const a = worldToCanvas(hw.x, hw.y), b = worldToCanvas(p.x, p.y);
      if (Math.hypot(a.x - b.x, a.y - b.y) <= HANDLE_R_PX + 3) return { kind: "rotate", v: sel };
    }
    const tol = 2 / state.view.scale;
    if (sel && contains(sel, p, tol)) return { kind: "move", v: sel };
    for (let i = state.vehicles.length - 1; i >= 0; i--) {
      if (contains(state.vehicles[i], p, tol)) return { kind: "move", v: state.vehicles[i] };
    }
    return { kind: "pan" };
  }

  canvas.addEventListener("pointerdown", (ev) => {
    if (ev.button !== 0 || !state.scene) return;
    canvas.focus();
    const p = eventWorld(ev);
    if (state.mode === "insert") {
      insertAt(p);
      return;
    }
    const hit = hitTest(p);
    if (hit.kind !== "pan") {
      state.selected = hit.v.id;
      refresh();
    } else if (state.selected !== null) {
      state.selected = null;
      refresh();
    }
    state.drag = {
      kind: hit.kind,
      v: hit.v || null,
      start: p,
      client: { x: ev.clientX, y: ev.clientY },
      view: { ...state.view },
      origin: hit.v ? hit.v.position.slice() : null,
      before: snapshot(),
      changed: false,
    };
    canvas.setPointerCapture(ev.pointerId);
    canvas.classList.add("dragging");
  });

  canvas.addEventListener("pointermove", (ev) => {
    const p = eventWorld(ev);
    $("cursor").textContent = `x ${p.x.toFixed(2)}  y ${p.y.toFixed(2)} m`;
    const d = state.drag;
    if (!d) return;
    if (d.kind === "pan") {
      state.view.cx = d.view.cx - (ev.clientX - d.client.x) / state.view.scale;
      state.view.cy = d.view.cy + (ev.clientY - d.client.y) / state.view.scale;
      draw();
      return;
    }
    if (!d.changed) {
      pushHistory(d.before);
      d.changed = true;
    }
    if (d.kind === "move") {
      d.v.position[0] = round(d.origin[0] + p.x - d.start.x, 3);
      d.v.position[1] = round(d.origin[1] + p.y - d.start.y, 3);
    } else {
      d.v.yaw = Math.atan2(p.y - d.v.position[1], p.x - d.v.position[0]);
    }
    markEdited(d.v);
    refresh();
  });

  function endDrag(ev) {
    if (!state.drag) return;
    state.drag = null;
    canvas.classList.remove("dragging");
    if (canvas.hasPointerCapture(ev.pointerId)) canvas.releasePointerCapture(ev.pointerId);
    refresh();
  }
  canvas.addEventListener("pointerup", endDrag);
  canvas.addEventListener("pointercancel", endDrag);

  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const r = canvas.getBoundingClientRect();
    const px = ev.clientX - r.left, py = ev.clientY - r.top;
    const before = canvasToWorld(px, py);
    const factor = Math.exp(-ev.deltaY * 0.0015);
    state.view.scale = Math.min(500, Math.max(0.05, state.view.scale * factor));
    const after = canvasToWorld(px, py);
    state.view.cx += before.x - after.x;
    state.view.cy += before.y - after.y;
    draw();
  }, { passive: false });

  document.addEventListener("keydown", (ev) => {
    const mod = ev.ctrlKey || ev.metaKey;
    const key = ev.key.toLowerCase();
    if (mod && key === "s") { ev.preventDefault(); save(); return; }
    if (ev.target instanceof HTMLInputElement && ev.target.type === "number") return;
    if (mod && key === "z") { ev.preventDefault(); undo(); return; }
    if (mod || ev.altKey) return;
    const step = ev.shiftKey ? Math.PI / 180 : ROTATE_STEP;
    if (ev.key === "Delete" || ev.key === "Backspace") { ev.preventDefault(); deleteSelected(); }
    else if (key === "q") rotateSelected(step);
    else if (key === "e") rotateSelected(-step);
    else if (key === "i") setMode(state.mode === "insert" ? "select" : "insert");
    else if (key === "f") fit();
    else if (ev.key === "Escape") {
      if (state.mode === "insert") setMode("select");
      else { state.selected = null; refresh(); }
    }
  });

  for (const key of Object.keys(inputs)) {
    inputs[key].addEventListener("change", () => applyInput(key));
  }
  $("btn-insert").addEventListener("click", () => setMode(state.mode === "insert" ? "select" : "insert"));
  $("btn-delete").addEventListener("click", deleteSelected);
  $("btn-rotate-left").addEventListener("click", () => rotateSelected(ROTATE_STEP));
  $("btn-rotate-right").addEventListener("click", () => rotateSelected(-ROTATE_STEP));
  $("btn-undo").addEventListener("click", undo);
  $("btn-fit").addEventListener("click", fit);
  $("btn-save").addEventListener("click", save);
  for (const layer of Object.keys(state.layers)) {
    $(`toggle-${layer}`).addEventListener("change", (ev) => {
      state.layers[layer] = ev.target.checked;
      draw();
    });
  }

  window.addEventListener("beforeunload", (ev) => {
    if (!isDirty()) return;
    ev.preventDefault();
    ev.returnValue = "You have unsaved changes.";  // older browsers need a non-empty string
    return ev.returnValue;
  });
  window.addEventListener("resize", resize);

  // -- loading -----------------------------------------------------------------------------
  function loadImage(url) {
    return new Promise((resolve) => {
      const img = new Image();
      img.onload = () => resolve(img);
      img.onerror = () => resolve(null);
      img.src = url;
    });
  }

  async function load() {
    try {
      const resp = await fetch("/api/scene");
      const scene = await resp.json();
      if (!resp.ok) throw new Error(scene.error || `HTTP ${resp.status}`);
      state.scene = scene;
      state.vehicles = scene.vehicles;
      state.savedJson = JSON.stringify(scene.vehicles);
      state.revision = scene.revision;
      $("ws-name").textContent = scene.workspace;
      if (scene.bev) state.bevImage = await loadImage(scene.bev.url);
      const layers = [
        `${scene.route.length} route points`,
        `${scene.lanes.length} map lanes`,
        scene.bev ? "LiDAR density" : "no LiDAR",
      ];
      $("layers-info").textContent = layers.join(", ");
      resize();
      fit();
      refresh();
      const what = scene.exists ? `${scene.vehicles.length} vehicles` : "no vehicle file yet";
      setStatus(`loaded ${scene.file}: ${what}`, "idle");
      document.body.dataset.ready = "true";
    } catch (err) {
      setStatus(`could not load the scene: ${err.message || err}`, "error");
    }
  }

  window.editor = {
    /** A copy of the current (unsaved) vehicle list. */
    vehicles: () => JSON.parse(JSON.stringify(state.vehicles)),
    /** The selected vehicle's id, or null. */
    selectedId: () => state.selected,
    /** World metres to viewport (client) pixels, as mouse events use them. */
    worldToScreen(x, y) {
      const r = canvas.getBoundingClientRect();
      const c = worldToCanvas(x, y);
      return { x: r.left + c.x, y: r.top + c.y };
    },
    /** Viewport (client) pixels to world metres. */
    screenToWorld(x, y) {
      const r = canvas.getBoundingClientRect();
      return canvasToWorld(x - r.left, y - r.top);
    },
    /** Where the selected vehicle's rotation handle is, in viewport pixels (or null). */
    rotateHandle() {
      const v = selectedVehicle();
      if (!v) return null;
      const hw = handleWorld(v);
      return this.worldToScreen(hw.x, hw.y);
    },
    view: () => ({ ...state.view }),
    isDirty,
    historyLength: () => state.history.length,
    scene: () => state.scene,
    fit,
  };

  load();
})();
