// The ICARS dashboard page: fetches /api/snapshot, folds trace records into a Model (model.js)
// and renders it — live from /api/events, or at a replay slider's time from /api/records.
// Rendering happens at most once per animation frame, whatever the rate records arrive at.
// Text from records is only ever set as textContent, never parsed as HTML.
(function () {
  "use strict";

  const { Model, formatTime } = window.IcarsModel;
  const SVG_NS = "http://www.w3.org/2000/svg";
  const KINDS = ["transition", "state", "task", "behavior", "event", "call", "command", "effect",
                 "speech", "note", "device", "policy", "robot", "user", "other"];
  const KINDS_OFF = new Set(["robot", "user"]);   // positions: many, and drawn on the map
  const TIMELINE_ROWS = 500;      // rows in the timeline's DOM
  const RECENT_RECORDS = 5000;    // records kept for the timeline (filtering looks this far back)
  const PAGE = 5000;              // records per /api/records request
  const CHECKPOINT_EVERY = 20000; // replay: a model clone every this many records
  const PAGE_CACHE = 16;          // replay: pages kept in memory
  const BACKFILL_MAX = 50000;     // live: fetch a run's first records when at most this many are missing
  const TOKEN_KEY = "icars-token";
  const ACTUATORS = new Set(["TV", "Light", "Speaker"]);   // devices whose state the map shows

  const app = {
    snapshot: null,
    model: null,
    mode: "live",
    token: "",
    connection: "connecting",
    dropped: 0,
    recent: [],          // the latest records applied, oldest first, for the timeline
    seq: 0,              // records pushed to `recent` so far
    renderedSeq: 0,      // the timeline shows records up to this seq
    timelineReset: true, // rebuild the timeline instead of prepending
    renderQueued: false,
    events: null,        // the EventSource
    pending: null,       // live records arriving while a snapshot is loading
    resyncing: false,
    viewTime: null,
    // replay
    replay: { start: 0, end: 0, target: 0, total: 0, folding: false, playing: false, rate: 60,
              pages: new Map(), inflight: new Map(), checkpoints: [], lastFrame: 0, progress: "" },
    // DOM caches
    dom: {},
  };

  // ---------------------------------------------------------------- utilities

  const $ = (sel) => document.querySelector(sel);

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    setAttrs(e, attrs);
    for (const c of children) if (c !== null && c !== undefined) e.append(c);
    return e;
  }

  function svg(tag, attrs, ...children) {
    const e = document.createElementNS(SVG_NS, tag);
    setAttrs(e, attrs);
    for (const c of children) if (c !== null && c !== undefined) e.append(c);
    return e;
  }

  function setAttrs(e, attrs) {
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "text") e.textContent = v;
      else e.setAttribute(k, v === true ? "" : String(v));
    }
  }

  // Sets or removes an attribute only when it changes (renders touch the DOM as little as they can).
  function attr(e, name, value) {
    if (value === null || value === undefined) {
      if (e.hasAttribute(name)) e.removeAttribute(name);
    } else if (e.getAttribute(name) !== String(value)) {
      e.setAttribute(name, String(value));
    }
  }

  function text(e, value) {
    const s = value === null || value === undefined ? "" : String(value);
    if (e.textContent !== s) e.textContent = s;
  }

  function round(v) { return Math.round(v * 1000) / 1000; }

  function duration(ms) {
    if (ms % 3600000 === 0) return ms / 3600000 + "h";
    if (ms % 60000 === 0) return ms / 60000 + "min";
    if (ms % 1000 === 0) return ms / 1000 + "s";
    return ms + "ms";
  }

  async function getJSON(url) {
    const res = await fetch(url, { cache: "no-store" });
    if (!res.ok) throw new Error(url + ": " + res.status + " " + res.statusText);
    return res.json();
  }

  function requestRender() {
    if (app.renderQueued) return;
    app.renderQueued = true;
    requestAnimationFrame(() => {
      app.renderQueued = false;
      render();
    });
  }

  // The control token: taken from the page's URL once, kept in sessionStorage, and removed from
  // the address bar so it does not stay in the history or a bookmark.
  function readToken() {
    const url = new URL(window.location.href);
    const fromUrl = url.searchParams.get("token");
    if (fromUrl) {
      sessionStorage.setItem(TOKEN_KEY, fromUrl);
      url.searchParams.delete("token");
      history.replaceState(null, "", url.pathname + url.search + url.hash);
    }
    return sessionStorage.getItem(TOKEN_KEY) || "";
  }

  // ---------------------------------------------------------------- records in

  function pushRecent(r) {
    app.recent.push(r);
    app.seq += 1;
    if (app.recent.length > RECENT_RECORDS * 1.5) app.recent.splice(0, app.recent.length - RECENT_RECORDS);
  }

  function clearRecent() {
    app.recent = [];
    app.timelineReset = true;
  }

  function applyRecord(r) {
    app.model.apply(r);
    pushRecent(r);
  }

  // A model for a snapshot, with the run's records before the snapshot's folded in when the server
  // has them and they are not too many; otherwise the model infers the running tasks. Returns the
  // model and the latest of those earlier records, for the timeline.
  async function modelFromSnapshot(snap) {
    const first = snap.first_index || 0;
    let model = new Model(snap);
    let earlier = [];
    if (first > 0 && first <= BACKFILL_MAX) {
      try {
        for (let from = 0; from < first; from += PAGE) {
          const page = await getJSON("/api/records?from=" + from + "&count=" + Math.min(PAGE, first - from));
          for (const r of page.records) model.apply(r);
          earlier = earlier.concat(page.records).slice(-RECENT_RECORDS);
        }
      } catch (e) {
        console.warn("dashboard: the run's first records are not available (" + e.message + "); inferring its state");
        model = new Model(snap);
        model.partial = true;
        earlier = [];
      }
    } else if (first > 0) {
      model.partial = true;
    }
    return { model, earlier };
  }

  // ---------------------------------------------------------------- live mode

  // The events are opened first and the snapshot fetched once the server has subscribed the page:
  // a record made between the two is queued (app.pending) and applied after the snapshot if the
  // snapshot does not hold it, so nothing from the run's start is missed. If the events cannot
  // open, the page shows the snapshot it has, disconnected.
  async function startLive(snap) {
    app.pending = [];
    if (await openEvents()) {
      try {
        snap = await getJSON("/api/snapshot");
      } catch (e) {
        console.warn("dashboard: the snapshot after subscribing failed (" + e.message + "); using the first");
      }
    }
    await loadLiveSnapshot(snap);
  }

  async function loadLiveSnapshot(snap) {
    const { model, earlier } = await modelFromSnapshot(snap);
    const sameStructure = app.snapshot && app.snapshot.policy && snap.policy &&
                          app.snapshot.policy.name === snap.policy.name;
    app.snapshot = snap;
    app.model = model;
    clearRecent();
    for (const r of earlier) pushRecent(r);
    for (const r of snap.records || []) applyRecord(r);
    const last = (snap.first_index || 0) + (snap.records || []).length - 1;
    if (model.lastIndex < last) model.lastIndex = last;
    const queued = app.pending || [];
    app.pending = null;
    for (const r of queued) liveRecord(r);
    if (!sameStructure) buildStatic();
    app.viewTime = null;
    requestRender();
  }

  function liveRecord(r) {
    if (app.pending) { app.pending.push(r); return; }
    if (typeof r.index === "number" && r.index <= app.model.lastIndex) return;  // already in the snapshot
    applyRecord(r);
    if (app.model.policyChanged && app.model.policyChanged !== app.resyncedFor) {
      app.resyncedFor = app.model.policyChanged;
      resync();   // another policy runs: its statechart and trees come with a new snapshot
    }
    requestRender();
  }

  async function resync() {
    if (app.resyncing) return;
    app.resyncing = true;
    app.pending = app.pending || [];
    try {
      const snap = await getJSON("/api/snapshot");
      await loadLiveSnapshot(snap);
    } catch (e) {
      app.pending = null;
      setConnection("disconnected");
      console.error("dashboard: resync failed:", e);
    } finally {
      app.resyncing = false;
    }
  }

  // Resolves true once the server has subscribed the page, false if the first attempt failed.
  function openEvents() {
    const events = new EventSource("/api/events");
    app.events = events;
    let hadError = false;
    let firstOpen;
    const opened = new Promise((resolve) => { firstOpen = resolve; });
    events.addEventListener("record", (e) => {
      let r;
      try { r = JSON.parse(e.data); } catch (err) { console.error("dashboard: bad record", e.data); return; }
      liveRecord(r);
    });
    events.addEventListener("dropped", (e) => {
      try { app.dropped += JSON.parse(e.data).dropped || 0; } catch (err) { app.dropped += 1; }
      requestRender();
      resync();
    });
    events.addEventListener("services", (e) => {
      try {
        const list = JSON.parse(e.data);
        if (app.model) app.model.setServices(list);
        if (app.snapshot) app.snapshot.services = list;
      } catch (err) { console.error("dashboard: bad services", e.data); }
      requestRender();
    });
    events.onopen = () => {
      setConnection("live");
      firstOpen(true);
      if (hadError) { hadError = false; resync(); }   // records may have been missed meanwhile
    };
    events.onerror = () => {
      hadError = true;
      firstOpen(false);
      setConnection("disconnected");
    };
    return opened;
  }

  function setConnection(state) {
    app.connection = state;
    requestRender();
  }

  // ---------------------------------------------------------------- replay mode

  function startReplay(snap) {
    const rp = app.replay;
    app.snapshot = snap;
    app.model = new Model(snap);
    rp.total = snap.total || 0;
    rp.start = snap.time.start_ms;
    rp.end = snap.time.end_ms ?? snap.time.start_ms;
    rp.checkpoints = [{ pos: 0, model: app.model.clone() }];
    rp.target = rp.start;
    setConnection("replay");
    buildStatic();
    const slider = $("#time-slider");
    slider.min = rp.start;
    slider.max = rp.end;
    slider.value = rp.start;
    slider.addEventListener("input", () => seek(Number(slider.value)));
    $("#replay-play").addEventListener("click", () => setPlaying(!rp.playing));
    $("#replay-rate").addEventListener("change", (e) => { rp.rate = Number(e.target.value); });
    rp.rate = Number($("#replay-rate").value);
    $("#replay").hidden = false;
    seek(rp.start);
  }

  function setPlaying(on) {
    const rp = app.replay;
    if (on && rp.target >= rp.end) seek(rp.start);
    rp.playing = on;
    $("#replay-play").textContent = on ? "Pause" : "Play";
    $("#replay-play").dataset.playing = String(on);
    if (on) {
      rp.lastFrame = performance.now();
      requestAnimationFrame(playFrame);
    }
  }

  function playFrame(now) {
    const rp = app.replay;
    if (!rp.playing) return;
    const dt = Math.min(now - rp.lastFrame, 250);
    rp.lastFrame = now;
    const next = Math.min(rp.end, rp.target + dt * rp.rate);
    $("#time-slider").value = next;
    seek(next);
    if (next >= rp.end) setPlaying(false);
    else requestAnimationFrame(playFrame);
  }

  function getPage(p) {
    const rp = app.replay;
    if (rp.pages.has(p)) {
      const records = rp.pages.get(p);
      rp.pages.delete(p);
      rp.pages.set(p, records);   // most recently used last
      return Promise.resolve(records);
    }
    if (rp.inflight.has(p)) return rp.inflight.get(p);
    const promise = getJSON("/api/records?from=" + p * PAGE + "&count=" + PAGE).then((res) => {
      rp.inflight.delete(p);
      rp.pages.set(p, res.records);
      if (typeof res.total === "number") rp.total = res.total;
      while (rp.pages.size > PAGE_CACHE) rp.pages.delete(rp.pages.keys().next().value);
      return res.records;
    }, (err) => { rp.inflight.delete(p); throw err; });
    rp.inflight.set(p, promise);
    return promise;
  }

  // Shows the state at time T: folds records forward from where the model is, or from the latest
  // checkpoint before T when the model is already past it. Only one fold runs; a newer target
  // redirects it.
  function seek(T) {
    const rp = app.replay;
    rp.target = T;
    app.viewTime = T;
    requestRender();
    if (!rp.folding) fold().catch((e) => {
      rp.folding = false;
      rp.progress = "cannot read the trace: " + e.message;
      setConnection("disconnected");
    });
  }

  function rewindTo(T) {
    const rp = app.replay;
    let best = rp.checkpoints[0];
    for (const cp of rp.checkpoints) {
      if (cp && cp.pos > best.pos && (cp.model.t === null || cp.model.t <= T)) best = cp;
    }
    app.model = best.model.clone();
    clearRecent();
    // The records just before the checkpoint, when still in memory, fill the timeline.
    const from = Math.max(0, best.pos - TIMELINE_ROWS);
    for (let i = from; i < best.pos; ++i) {
      const page = rp.pages.get(Math.floor(i / PAGE));
      if (page && page[i % PAGE]) pushRecent(page[i % PAGE]);
    }
  }

  async function fold() {
    const rp = app.replay;
    rp.folding = true;
    const began = performance.now();
    let slice = performance.now();
    for (;;) {
      const T = rp.target;
      if (app.model.t !== null && app.model.t > T) rewindTo(T);
      const pos = app.model.count;
      if (pos >= rp.total) break;
      const p = Math.floor(pos / PAGE);
      const page = await getPage(p);
      if (p + 1 < Math.ceil(rp.total / PAGE)) getPage(p + 1).catch(() => {});   // read ahead
      if (rp.target < T || (app.model.t !== null && app.model.t > rp.target)) continue;  // moved back meanwhile
      if (app.model.count !== pos) continue;
      let i = pos - p * PAGE;
      let reached = false;
      for (; i < page.length; ++i) {
        const r = page[i];
        if (r.t > rp.target) { reached = true; break; }
        applyRecord(r);
        if (app.model.count % CHECKPOINT_EVERY === 0) {
          const k = app.model.count / CHECKPOINT_EVERY;
          if (!rp.checkpoints[k]) rp.checkpoints[k] = { pos: app.model.count, model: app.model.clone() };
        }
      }
      if (page.length === 0) break;   // the trace is shorter than `total` said
      if (reached && rp.target === T) break;
      if (performance.now() - slice > 25) {
        if (performance.now() - began > 300) {
          rp.progress = "reading the trace: " + Math.round((100 * app.model.count) / Math.max(1, rp.total)) + "%";
        }
        requestRender();
        await new Promise((resolve) => setTimeout(resolve, 0));
        slice = performance.now();
      }
    }
    rp.folding = false;
    rp.progress = "";
    requestRender();
  }

  // ---------------------------------------------------------------- static views

  function buildStatic() {
    buildMap();
    buildStatechart();
    buildTrees();
    buildServicesTable();
    buildControls();
    text($("#house-name"), app.snapshot.house.name || "");
    text($("#policy-title"), app.snapshot.policy ? "· " + (app.snapshot.policy.name || "") : "");
  }

  // ---- map

  function buildMap() {
    const house = app.snapshot.house;
    const b = house.bounds || { x0: 0, y0: 0, x1: 10, y1: 5 };
    const margin = 0.5;
    const X = (x) => round(x - b.x0);
    const Y = (y) => round(b.y1 - y);
    app.dom.X = X;
    app.dom.Y = Y;
    const map = $("#map");
    map.replaceChildren();
    const w = b.x1 - b.x0, h = b.y1 - b.y0;
    map.setAttribute("viewBox", [-margin, -margin, w + 2 * margin, h + 2 * margin].map(round).join(" "));
    map.dataset.house = house.name || "";

    const layer = (name) => map.appendChild(svg("g", { class: "layer-" + name }));
    const rooms = layer("rooms"), furniture = layer("furniture"), walls = layer("walls"),
          waypoints = layer("waypoints"), devices = layer("devices"), tracks = layer("tracks"),
          targets = layer("targets"), users = layer("users"), robots = layer("robots");

    for (const r of house.rooms || []) {
      rooms.append(svg("rect", { class: "room", "data-room": r.name, x: X(r.x0), y: Y(r.y1),
                                 width: round(r.x1 - r.x0), height: round(r.y1 - r.y0) }));
      rooms.append(svg("text", { class: "room-label", x: X(r.x0) + 0.05, y: Y(r.y1) - 0.1, text: r.name }));
    }
    for (const f of house.furniture || []) {
      const g = svg("g", { class: "furniture" + (f.blocks === false || f.kind === "rug" ? " nonblocking" : ""),
                           "data-furniture": f.name, "data-kind": f.kind });
      g.append(svg("rect", { x: X(f.x0), y: Y(f.y1), width: round(f.x1 - f.x0), height: round(f.y1 - f.y0) }),
               svg("text", { x: X(f.x0) + 0.05, y: Y(f.y1) + 0.16, text: f.name }),
               svg("title", { text: f.name + " (" + f.kind + ")" }));
      furniture.append(g);
    }
    if ((house.walls || []).length) {
      for (const s of house.walls) {
        walls.append(svg("line", { class: "wall", x1: X(s.x0), y1: Y(s.y0), x2: X(s.x1), y2: Y(s.y1) }));
      }
    } else {
      for (const r of house.rooms || []) {   // no wall list: the rooms' outlines
        walls.append(svg("rect", { class: "wall", fill: "none", x: X(r.x0), y: Y(r.y1),
                                   width: round(r.x1 - r.x0), height: round(r.y1 - r.y0) }));
      }
    }
    for (const d of house.doors || []) {
      walls.append(svg("line", { class: "door", "data-door": d.name, x1: X(d.x0), y1: Y(d.y0), x2: X(d.x1), y2: Y(d.y1) },
                       svg("title", { text: d.name })));
    }
    for (const wp of house.waypoints || []) {
      const s = 0.07;
      const g = svg("g", { class: "waypoint", "data-waypoint": wp.name, "data-tags": (wp.tags || []).join(" "),
                           transform: "translate(" + X(wp.x) + " " + Y(wp.y) + ")" });
      g.append(svg("path", { d: `M${-s} ${-s}L${s} ${s}M${-s} ${s}L${s} ${-s}` }),
               svg("text", { x: 0.09, y: -0.05, text: wp.name }),
               svg("title", { text: wp.name + ((wp.tags || []).length ? " [" + wp.tags.join(", ") + "]" : "") }));
      waypoints.append(g);
    }

    app.dom.devices = new Map();
    for (const d of house.devices || []) {
      if (d.carrier) continue;
      const g = svg("g", { class: "device", "data-device": d.id, "data-type": d.type, "data-room": d.room || "",
                           transform: "translate(" + X(d.x) + " " + Y(d.y) + ")" });
      const sensor = !ACTUATORS.has(d.type);
      const state = svg("text", { class: "state", x: 0.15, y: 0.2 });
      const title = svg("title", { text: d.id + " (" + d.type + ")" });
      if (sensor) {   // sensors: a small mark, named in its tooltip (their labels would hide the map)
        g.classList.add("sensor");
        g.append(svg("rect", { x: -0.06, y: -0.06, width: 0.12, height: 0.12, transform: "rotate(45)" }), title);
      } else {
        g.append(svg("circle", { r: 0.11 }), svg("text", { class: "label", x: 0.15, y: 0.04, text: d.id }), state, title);
      }
      devices.append(g);
      app.dom.devices.set(d.id, { g, state, title, type: d.type });
    }

    app.dom.robots = new Map();
    for (const r of house.robots || []) addRobot(r.id, r.radius || 0.25, tracks, targets, robots);
    app.dom.users = new Map();
    for (const u of house.users || []) addUser(u.id, u.radius || 0.2, users);
    app.dom.layers = { tracks, targets, robots, users };
  }

  function addRobot(id, radius, tracks, targets, robots) {
    const house = app.snapshot.house;
    const track = svg("polyline", { class: "track", "data-robot-track": id, points: "" });
    tracks.append(track);
    const targetLine = svg("line", { class: "target-line" });
    const targetMark = svg("circle", { class: "target-mark", r: 0.12 });
    const targetLabel = svg("text", { class: "target-label" });
    const target = svg("g", { class: "target", "data-robot-target": id, visibility: "hidden" },
                       targetLine, targetMark, targetLabel);
    targets.append(target);
    const heading = svg("line", { x1: 0, y1: 0, x2: radius, y2: 0 });
    const g = svg("g", { class: "robot", "data-robot": id });
    const carried = svg("g", { class: "carried" });
    g.append(svg("circle", { r: radius }), heading, svg("text", { x: radius + 0.06, y: -0.05, text: id }), carried,
             svg("title", { text: id }));
    robots.append(g);
    const devices = [];
    for (const d of house.devices || []) {
      if (d.carrier !== id) continue;
      const state = svg("text", { class: "state", x: radius + 0.06, y: 0.14 });
      const dg = svg("g", { class: "device carried", "data-device": d.id, "data-type": d.type }, state,
                     svg("title", { text: d.id + " (" + d.type + ")" }));
      carried.append(dg);
      devices.push(state);
      app.dom.devices.set(d.id, { g: dg, state, title: null, type: d.type, carried: true });
    }
    app.dom.robots.set(id, { g, heading, track, target, targetLine, targetMark, targetLabel, radius, devices });
  }

  function addUser(id, radius, users) {
    const posture = svg("text", { class: "posture", x: radius + 0.05, y: 0.15 });
    const g = svg("g", { class: "user", "data-user": id });
    g.append(svg("circle", { r: radius }), svg("text", { x: radius + 0.05, y: -0.03, text: id }), posture,
             svg("title", { text: id }));
    users.append(g);
    app.dom.users.set(id, { g, posture });
  }

  // ---- statechart

  function buildStatechart() {
    const root = $("#statechart");
    root.replaceChildren();
    app.dom.states = new Map();
    const chart = app.snapshot.policy && app.snapshot.policy.statechart;
    if (!chart) { root.append(el("p", { class: "empty", text: "no policy" })); return; }
    const build = (node, isRoot) => {
      const box = el("div", { class: "state" + (isRoot ? " chart" : ""), "data-state": node.name,
                              "data-kind": node.kind || "state" });
      const head = el("div", { class: "state-head" }, el("span", { class: "state-name", text: node.name }));
      if (node.task) head.append(el("span", { class: "state-task", text: "task " + node.task }));
      box.append(head);
      if ((node.transitions || []).length) {
        const list = el("ul", { class: "transitions" });
        for (const t of node.transitions) {
          const on = t.event ? t.event : t.after_ms !== null && t.after_ms !== undefined ? "after " + duration(t.after_ms) : "?";
          list.append(el("li", { "data-event": t.event || "", "data-target": t.target,
                                 text: on + " → " + t.target + (t.guard ? " [" + t.guard + "]" : "") }));
        }
        box.append(list);
      }
      for (const c of node.children || []) box.append(build(c, false));
      app.dom.states.set(node.name, box);
      return box;
    };
    root.append(build(chart, true));
    app.dom.transitionsKey = null;
  }

  // ---- behavior trees

  function buildTrees() {
    const root = $("#behavior-trees");
    root.replaceChildren();
    app.dom.tasks = new Map();
    app.dom.nodes = new Map();
    app.dom.taskOrder = "";
    const tasks = (app.snapshot.policy && app.snapshot.policy.tasks) || {};
    const names = Object.keys(tasks);
    if (!names.length) { root.append(el("p", { class: "empty", text: "no tasks" })); return; }
    const build = (node, prefix) => {
      const name = node.name || node.type || "?";
      const path = prefix + "/" + name;
      const last = el("span", { class: "last" });
      const status = el("span", { class: "status" });
      const box = el("div", { class: "bt-node", "data-node": path, "data-type": node.type || "", "data-status": "idle" },
                     el("span", { class: "name", text: name }),
                     node.type && node.type !== name ? el("span", { class: "type", text: node.type }) : null,
                     status, last);
      app.dom.nodes.set(path, { box, status, last });
      const li = el("li", null, box);
      if ((node.children || []).length) {
        const ul = el("ul");
        for (const c of node.children) ul.append(build(c, path));
        li.append(ul);
      }
      return li;
    };
    for (const task of names) {
      const status = el("span", { class: "task-status" });
      const details = el("details", { class: "bt", "data-task": task, "data-task-status": "idle" },
                         el("summary", null, task + " ", status),
                         el("ul", { class: "bt-tree" }, build(tasks[task], task)));
      root.append(details);
      app.dom.tasks.set(task, { details, status, was: "idle" });
    }
  }

  // ---- services

  function buildServicesTable() {
    app.dom.services = new Map();
    $("#services tbody").replaceChildren();
  }

  // ---- timeline filters (built once)

  function buildTimelineFilters() {
    const kinds = $("#timeline-kinds");
    for (const k of KINDS) {
      const box = el("input", { type: "checkbox", id: "kind-" + k, "data-kind": k });
      box.checked = !KINDS_OFF.has(k);
      box.addEventListener("change", () => { app.timelineReset = true; requestRender(); });
      kinds.append(el("label", null, box, " " + k));
    }
    $("#timeline-filter").addEventListener("input", () => { app.timelineReset = true; requestRender(); });
  }

  // ---- controls

  function buildControls() {
    const panel = $("#controls");
    if (!app.snapshot.controls || app.mode !== "live") { panel.hidden = true; return; }
    panel.hidden = false;
    const select = $("#say-user");
    select.replaceChildren();
    for (const u of app.snapshot.house.users || []) select.append(el("option", { value: u.id, text: u.id }));
    const names = $("#policy-names");
    names.replaceChildren();
    if (app.snapshot.policy && app.snapshot.policy.name) {
      names.append(el("option", { value: app.snapshot.policy.name }));
      if (!$("#policy-name").value) $("#policy-name").value = app.snapshot.policy.name;
    }
    if (!app.token) {
      showError($("#run-error"), "The controls need the token: open the address icars printed " +
                                 "(http://HOST:PORT/?token=...).");
    }
    if (app.dom.controlsWired) return;
    app.dom.controlsWired = true;
    $("#say-form").addEventListener("submit", (e) => {
      e.preventDefault();
      const body = { user: $("#say-user").value, text: $("#say-text").value.trim() };
      if (!body.text) { showError($("#say-error"), "Type what the user says."); return; }
      control("/api/say", body, $("#say-error"), $("#say-send"), () => { $("#say-text").value = ""; });
    });
    $("#policy-form").addEventListener("submit", (e) => {
      e.preventDefault();
      const name = $("#policy-name").value.trim();
      if (!name) { showError($("#policy-error"), "Name the policy to load."); return; }
      control("/api/policy", { name }, $("#policy-error"), $("#policy-load"), () => {});
    });
    $("#pause").addEventListener("click", () => control("/api/pause", {}, $("#run-error"), $("#pause"), () => {}));
    $("#resume").addEventListener("click", () => control("/api/resume", {}, $("#run-error"), $("#resume"), () => {}));
    $("#speed-form").addEventListener("submit", (e) => {
      e.preventDefault();
      const speed = Number($("#speed-value").value);
      if (!(speed > 0)) { showError($("#speed-error"), "The speed is simulated seconds per second, more than 0."); return; }
      control("/api/speed", { speed }, $("#speed-error"), $("#speed-set"), () => {});
    });
  }

  function showError(pre, message) {
    pre.textContent = message;
    pre.hidden = false;
  }

  // A control request: the token goes in the Authorization header, nowhere else. A 4xx/5xx
  // answer's `error` is shown in `errorEl`, next to the control that sent it.
  async function control(path, body, errorEl, button, onOk) {
    errorEl.hidden = true;
    errorEl.textContent = "";
    button.disabled = true;
    button.dataset.state = "pending";
    try {
      const res = await fetch(path, {
        method: "POST",
        cache: "no-store",
        headers: Object.assign({ "Content-Type": "application/json" },
                               app.token ? { Authorization: "Bearer " + app.token } : {}),
        body: JSON.stringify(body),
      });
      let data = null;
      try { data = await res.json(); } catch (e) { data = null; }
      if (!res.ok) {
        showError(errorEl, (data && data.error) || res.status + " " + res.statusText);
        button.dataset.state = "error";
        return;
      }
      button.dataset.state = "ok";
      onOk(data);
    } catch (e) {
      showError(errorEl, path + " failed: " + e.message);
      button.dataset.state = "error";
    } finally {
      button.disabled = false;
    }
  }

  // ---------------------------------------------------------------- render

  function render() {
    if (!app.model) return;
    const m = app.model;
    const time = app.viewTime !== null ? app.viewTime : m.t;
    text($("#clock"), formatTime(time, false));
    const active = m.activeStates();
    text($("#active-states"), active.join(", "));
    renderConnection();
    renderMap(m);
    renderStatechart(m, active);
    renderTrees(m);
    renderServices(m);
    renderTimeline();
    if (app.mode === "replay") {
      text($("#replay-time"), formatTime(app.replay.target, false));
      text($("#replay-progress"), app.replay.progress);
    }
  }

  function renderConnection() {
    const badge = $("#connection");
    let label = app.connection;
    if (app.connection === "live" && app.model && app.model.partial) label += " · from record " + app.snapshot.first_index;
    if (app.dropped) label += " · dropped " + app.dropped;
    attr(badge, "data-state", app.connection);
    attr(badge, "data-dropped", app.dropped);
    text(badge, label);
  }

  function deviceSummary(type, d) {
    const parts = [];
    if (d.on === true) parts.push("on");
    else if (d.on === false) parts.push("off");
    if (d.channel !== undefined && d.on !== false) parts.push("ch " + d.channel);
    if (d.volume !== undefined && (type === "TV" ? d.on !== false : d.playing)) parts.push("vol " + d.volume);
    if (d.intensity !== undefined && d.on !== false) parts.push(d.intensity + "%");
    if (d.playing) parts.push("♪ " + d.playing);
    if (d.spoke && !d.playing) parts.push("“" + d.spoke + "”");
    if (d.lost) parts.push("lost");
    return parts.join(" · ");
  }

  function renderMap(m) {
    const { X, Y } = app.dom;
    for (const [id, view] of app.dom.devices) {
      const d = m.devices[id] || {};
      attr(view.g, "data-on", d.on === undefined ? null : String(d.on));
      attr(view.g, "data-channel", d.channel ?? null);
      attr(view.g, "data-volume", d.volume ?? null);
      attr(view.g, "data-playing", d.playing || null);
      attr(view.g, "data-lost", d.lost ? "true" : null);
      text(view.state, deviceSummary(view.type, d));
    }
    for (const [id, r] of Object.entries(m.robots)) {
      let view = app.dom.robots.get(id);
      if (!view) {
        const L = app.dom.layers;
        addRobot(id, r.radius || 0.25, L.tracks, L.targets, L.robots);
        view = app.dom.robots.get(id);
      }
      attr(view.g, "transform", "translate(" + X(r.x) + " " + Y(r.y) + ")");
      attr(view.g, "data-moving", String(!!r.moving));
      attr(view.g, "data-x", round(r.x));
      attr(view.g, "data-y", round(r.y));
      if (r.heading !== null && r.heading !== undefined) {
        attr(view.heading, "x2", round(Math.cos(r.heading) * view.radius));
        attr(view.heading, "y2", round(-Math.sin(r.heading) * view.radius));
      }
      let line = 0;
      for (const state of view.devices) {
        if (state.textContent) attr(state, "y", round(0.14 + 0.17 * line++));
      }
      const track = r.track.length > 200 ? r.track.slice(-200) : r.track;
      attr(view.track, "points", track.map((p) => X(p[0]) + "," + Y(p[1])).join(" "));
      if (r.target && r.target.x !== null) {
        attr(view.target, "visibility", "visible");
        attr(view.target, "data-target", r.target.label);
        attr(view.targetLine, "x1", X(r.x)); attr(view.targetLine, "y1", Y(r.y));
        attr(view.targetLine, "x2", X(r.target.x)); attr(view.targetLine, "y2", Y(r.target.y));
        attr(view.targetMark, "cx", X(r.target.x)); attr(view.targetMark, "cy", Y(r.target.y));
        attr(view.targetLabel, "x", X(r.target.x) + 0.15); attr(view.targetLabel, "y", Y(r.target.y) + 0.2);
        text(view.targetLabel, "→ " + r.target.label);
      } else {
        attr(view.target, "visibility", "hidden");
        attr(view.target, "data-target", r.target ? r.target.label : null);
      }
    }
    for (const [id, u] of Object.entries(m.users)) {
      let view = app.dom.users.get(id);
      if (!view) { addUser(id, u.radius || 0.2, app.dom.layers.users); view = app.dom.users.get(id); }
      attr(view.g, "transform", "translate(" + X(u.x) + " " + Y(u.y) + ")");
      attr(view.g, "data-posture", u.posture);
      attr(view.g, "data-room", u.room);
      attr(view.g, "data-furniture", u.furniture || null);
      text(view.posture, u.posture + (u.furniture ? " on " + u.furniture : ""));
    }
  }

  function renderStatechart(m, active) {
    const on = new Set(active);
    const chart = app.snapshot.policy && app.snapshot.policy.statechart;
    if (chart && m.policyRunning) on.add(chart.name);
    for (const [name, box] of app.dom.states) {
      const isOn = on.has(name);
      if (box.classList.contains("active") !== isOn) box.classList.toggle("active", isOn);
      attr(box, "data-active", String(isOn));
    }
    const log = m.transitions;
    const key = log.length ? log.length + "|" + log[log.length - 1].t + "|" + log[log.length - 1].text : "0";
    if (key === app.dom.transitionsKey) return;
    app.dom.transitionsKey = key;
    const list = $("#transition-log");
    const items = [];
    for (let i = log.length - 1; i >= 0; --i) {
      const t = log[i];
      items.push(el("li", { "data-from": t.from, "data-to": t.to, "data-event": t.event },
                    el("span", { class: "time", text: t.time || formatTime(t.t, true) }),
                    t.text || t.from + " -> " + t.to + " on " + t.event));
    }
    list.replaceChildren(...items);
  }

  function renderTrees(m) {
    const order = [];
    for (const [task, view] of app.dom.tasks) {
      const info = m.tasks[task];
      const status = info ? info.status : "idle";
      attr(view.details, "data-task-status", status);
      text(view.status, status === "idle" ? "" : status + (info && info.reason ? ": " + info.reason : ""));
      if (status !== view.was) {
        if (status === "running") view.details.open = true;
        else if (view.was === "running") view.details.open = false;
        view.was = status;
      }
      order.push([status === "running" ? 0 : 1, task]);
    }
    order.sort((a, b) => a[0] - b[0]);
    const key = order.map((o) => o[1]).join(",");
    if (key !== app.dom.taskOrder) {
      app.dom.taskOrder = key;
      const root = $("#behavior-trees");
      for (const [, task] of order) root.append(app.dom.tasks.get(task).details);
    }
    for (const [path, view] of app.dom.nodes) {
      const n = m.nodes[path];
      attr(view.box, "data-status", n ? n.status : "idle");
      text(view.status, n ? n.status : "");
      attr(view.box, "title", n && n.reason ? n.reason : null);
      const last = m.nodeLast[path];
      text(view.last, last ? formatTime(last.t, false).split(" ")[1] + " " + last.text : "");
      attr(view.box, "data-last-kind", last ? last.kind : null);
    }
  }

  function renderServices(m) {
    const body = $("#services tbody");
    const ids = Object.keys(m.services).sort();
    const seen = new Set();
    let previous = null;
    for (const id of ids) {
      const s = m.services[id];
      let row = app.dom.services.get(id);
      if (!row) {
        row = { tr: el("tr", { "data-service": id }), cells: [] };
        for (let i = 0; i < 5; ++i) { const td = el("td"); row.cells.push(td); row.tr.append(td); }
        app.dom.services.set(id, row);
      }
      const available = s.available !== false;
      attr(row.tr, "data-available", String(available));
      attr(row.tr, "data-service-device", s.device || null);
      text(row.cells[0], id);
      text(row.cells[1], s.type || "");
      text(row.cells[2], s.room || "—");
      text(row.cells[3], s.carrier || "—");
      text(row.cells[4], available ? "yes" : "no");
      const expected = previous ? previous.tr.nextSibling : body.firstChild;
      if (expected !== row.tr) body.insertBefore(row.tr, expected);
      previous = row;
      seen.add(id);
    }
    for (const [id, row] of app.dom.services) {
      if (!seen.has(id)) { row.tr.remove(); app.dom.services.delete(id); }
    }
  }

  function timelineFilter() {
    const kinds = new Set();
    for (const box of document.querySelectorAll("#timeline-kinds input")) if (box.checked) kinds.add(box.dataset.kind);
    const needle = $("#timeline-filter").value.trim().toLowerCase();
    return (r) => {
      const kind = KINDS.includes(r.kind) ? r.kind : "other";
      if (!kinds.has(kind)) return false;
      if (!needle) return true;
      return ((r.text || "") + " " + (r.source || "") + " " + r.kind).toLowerCase().includes(needle);
    };
  }

  function timelineRow(r) {
    const li = el("li", { "data-kind": r.kind, "data-source": r.source, "data-event": r.event || null,
                          "data-ok": r.ok === false ? "false" : null, "data-index": r.index ?? null, title: r.text },
                  el("span", { class: "time", text: r.time || formatTime(r.t, true) }),
                  el("span", { class: "kind", text: r.kind }),
                  r.text || "");
    return li;
  }

  function renderTimeline() {
    const list = $("#timeline");
    const fresh = app.seq - app.renderedSeq;
    if (fresh === 0 && !app.timelineReset) return;
    const keep = timelineFilter();
    if (app.timelineReset || fresh > TIMELINE_ROWS || fresh > app.recent.length) {
      const rows = [];
      for (let i = app.recent.length - 1; i >= 0 && rows.length < TIMELINE_ROWS; --i) {
        if (keep(app.recent[i])) rows.push(timelineRow(app.recent[i]));
      }
      list.replaceChildren(...rows);
    } else {
      const rows = [];
      for (let i = app.recent.length - 1; i >= app.recent.length - fresh; --i) {
        if (keep(app.recent[i])) rows.push(timelineRow(app.recent[i]));
      }
      if (rows.length) list.prepend(...rows);
      while (list.childElementCount > TIMELINE_ROWS) list.lastElementChild.remove();
    }
    app.timelineReset = false;
    app.renderedSeq = app.seq;
  }

  // ---------------------------------------------------------------- start

  async function start() {
    app.token = readToken();
    buildTimelineFilters();
    let snap;
    try {
      snap = await getJSON("/api/snapshot");
    } catch (e) {
      setConnection("disconnected");
      text($("#connection"), "disconnected: " + e.message);
      return;
    }
    app.mode = snap.mode === "replay" ? "replay" : "live";
    document.body.dataset.mode = app.mode;
    if (app.mode === "replay") startReplay(snap);
    else await startLive(snap);
  }

  app.renderNow = render;        // for browser tests: render without waiting for a frame
  window.icarsDashboard = app;   // for scripting and browser tests: the model is app.model
  start();
})();
