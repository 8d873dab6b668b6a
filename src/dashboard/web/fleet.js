// The COROS fleet page (docs/dashboard.md, "The fleet page"): `icars-coros run ... --http` feeds
// it the agents' events, the runner's notes and the robots' positions as records; the page folds
// them into a model (robots, neighbour tables, auctions round by round, deliveries) and draws it.
// Plain JavaScript, no build step, nothing fetched but this server's API.
"use strict";

(() => {
  const SVG_NS = "http://www.w3.org/2000/svg";
  const TRACK_POINTS = 600;   // points of a robot's track kept for the map
  const LOG_ROWS = 400;       // rows of the event list
  const COLORS = ["#2563c9", "#d9480f", "#2b8a3e", "#862e9c", "#c2255c", "#0b7285", "#e67700", "#5f3dc4"];

  const $ = (sel) => document.querySelector(sel);

  function setAttrs(e, attrs) {
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined) continue;
      if (k === "text") e.textContent = v;
      else if (k === "class") e.setAttribute("class", v);
      else e.setAttribute(k, String(v));
    }
  }
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
  const round = (v) => Math.round(v * 1000) / 1000;
  const cost = (v) => (typeof v === "number" ? v.toFixed(2) : "?");

  // ---------------------------------------------------------------- the model

  function newModel() {
    return {
      lastIndex: -1,
      lastTime: "",
      plan: null,            // the scenario's plan record
      robots: new Map(),     // id -> {id, x, y, moving, track, alive, killed, task, round, stage, distance, color}
      neighbors: new Map(),  // agent -> Map(neighbour -> role)
      tasks: new Map(),      // task -> {task, pickup, dropoff, rounds: Map, outcome, robot, detail, stages}
      log: [],
      summary: null,         // {success, text}
    };
  }

  function robot(m, id) {
    let r = m.robots.get(id);
    if (!r) {
      r = { id, x: null, y: null, moving: false, track: [], alive: true, killed: "", task: "", round: null,
            stage: "", distance: 0, color: COLORS[m.robots.size % COLORS.length] };
      m.robots.set(id, r);
    }
    return r;
  }

  function task(m, id) {
    let t = m.tasks.get(id);
    if (!t) {
      t = { task: id, pickup: "", dropoff: "", rounds: new Map(), outcome: "running", robot: "", detail: "", stages: [] };
      m.tasks.set(id, t);
    }
    return t;
  }

  function roundOf(t, n) {
    const k = Number(n) || 1;
    let r = t.rounds.get(k);
    if (!r) {
      r = { round: k, bids: new Map(), late: new Map(), declined: new Map(), winner: "", cost: null, assigned: false, reauction: null,
            excluded: [], state: "open", endedBy: "" };
      t.rounds.set(k, r);
    }
    return r;
  }

  function fold(m, rec) {
    if (typeof rec.index === "number") {
      if (rec.index <= m.lastIndex) return;
      m.lastIndex = rec.index;
    }
    m.lastTime = rec.time || m.lastTime;
    if (rec.kind !== "robot") {
      m.log.push(rec);
      if (m.log.length > LOG_ROWS) m.log.splice(0, m.log.length - LOG_ROWS);
    }
    if (rec.kind === "robot") return foldPosition(m, rec);
    if (rec.kind === "scenario") return foldNote(m, rec);
    if (rec.kind === "agent") return foldEvent(m, rec);
  }

  function foldPosition(m, rec) {
    const r = robot(m, rec.robot);
    for (const p of rec.path || []) r.track.push(p);
    if (r.track.length > TRACK_POINTS) r.track.splice(0, r.track.length - TRACK_POINTS);
    r.x = rec.x;
    r.y = rec.y;
    r.moving = !!rec.moving;
    if (typeof rec.distance === "number") r.distance = rec.distance;
  }

  function foldNote(m, rec) {
    if (rec.event === "plan") {
      m.plan = rec;
      for (const p of rec.robots || []) {
        const r = robot(m, p.id);
        if (r.x === null) { r.x = p.x; r.y = p.y; r.track.push([p.x, p.y]); }
      }
    } else if (rec.event === "killed") {
      const r = robot(m, rec.robot);
      r.alive = false;
      r.killed = rec.reason || "killed";
      r.moving = false;
    } else if (rec.event === "exited" && !rec.expected && m.robots.has(rec.agent)) {
      const r = robot(m, rec.agent);
      r.alive = false;
      r.killed = r.killed || rec.text;
    } else if (rec.event === "summary") {
      m.summary = { success: !!rec.success, text: rec.text };
      for (const r of m.robots.values()) r.moving = false;
    }
  }

  function foldEvent(m, e) {
    const agent = e.source;
    switch (e.event) {
      case "neighbor_joined":
      case "neighbor_left": {
        if (!m.neighbors.has(agent)) m.neighbors.set(agent, new Map());
        const table = m.neighbors.get(agent);
        if (e.event === "neighbor_joined") table.set(e.neighbor, e.role || "");
        else table.delete(e.neighbor);
        break;
      }
      case "started":
        if (!m.neighbors.has(agent)) m.neighbors.set(agent, new Map());
        if (e.role === "robot") robot(m, agent);
        break;
      case "auction": {
        const t = task(m, e.task);
        t.pickup = e.pickup || t.pickup;
        t.dropoff = e.dropoff || t.dropoff;
        const r = roundOf(t, e.round);
        r.excluded = e.exclude || [];
        break;
      }
      case "bid_received": {
        const r = roundOf(task(m, e.task), e.round);
        (r.winner ? r.late : r.bids).set(e.robot, e.cost);
        break;
      }
      case "declined":
        roundOf(task(m, e.task), e.round).declined.set(e.robot, e.reason || "");
        break;
      case "awarded": {
        const r = roundOf(task(m, e.task), e.round);
        for (const [id, c] of Object.entries(e.bids || {})) r.bids.set(id, c);
        r.winner = e.robot;
        r.cost = e.cost;
        r.state = "awarded";
        break;
      }
      case "assigned": {
        const r = roundOf(task(m, e.task), e.round);
        r.assigned = true;
        if (r.state === "awarded" || r.state === "open") r.state = "assigned";
        break;
      }
      case "reauction": {
        const t = task(m, e.task);
        const next = roundOf(t, e.round);
        next.reauction = e.reason || "auctioned again";
        const before = t.rounds.get((Number(e.round) || 2) - 1);
        if (before) { before.state = before.winner ? "reauctioned" : "no-bids"; before.endedBy = e.reason || ""; }
        break;
      }
      case "task_stage": {
        const r = robot(m, agent);
        r.task = e.task;
        r.round = e.round;
        r.stage = e.stage;
        task(m, e.task).stages.push({ robot: agent, round: e.round, stage: e.stage, time: e.time });
        break;
      }
      case "dropped": {
        const r = robot(m, agent);
        if (r.task === e.task) r.stage = "dropped";
        task(m, e.task).stages.push({ robot: agent, round: e.round, stage: "dropped: " + (e.reason || ""), time: e.time });
        break;
      }
      case "delivery_finished": {
        const t = task(m, e.task);
        t.outcome = e.success ? "delivered" : "failed";
        t.robot = e.robot || "";
        t.detail = e.detail || "";
        t.distance = e.distance;
        break;
      }
    }
  }

  // ---------------------------------------------------------------- drawing

  const view = { model: newModel(), snapshot: null, X: (x) => x, Y: (y) => y, connection: "connecting", pending: false };

  function buildMap(house) {
    const map = $("#map");
    map.replaceChildren();
    if (!house) return;
    const b = house.bounds || { x0: 0, y0: 0, x1: 10, y1: 5 };
    const margin = 0.5;
    view.X = (x) => round(x - b.x0);
    view.Y = (y) => round(b.y1 - y);
    const X = view.X, Y = view.Y;
    map.setAttribute("viewBox", [-margin, -margin, b.x1 - b.x0 + 2 * margin, b.y1 - b.y0 + 2 * margin].map(round).join(" "));
    map.dataset.house = house.name || "";
    const layer = (name) => map.appendChild(svg("g", { class: "layer-" + name }));
    const rooms = layer("rooms"), walls = layer("walls"), waypoints = layer("waypoints");
    for (const r of house.rooms || []) {
      rooms.append(svg("rect", { class: "room", "data-room": r.name, x: X(r.x0), y: Y(r.y1),
                                 width: round(r.x1 - r.x0), height: round(r.y1 - r.y0) }),
                   svg("text", { class: "room-label", x: X(r.x0) + 0.05, y: Y(r.y1) - 0.1, text: r.name }));
    }
    for (const f of house.furniture || []) {
      rooms.append(svg("g", { class: "furniture", "data-furniture": f.name },
                       svg("rect", { x: X(f.x0), y: Y(f.y1), width: round(f.x1 - f.x0), height: round(f.y1 - f.y0) })));
    }
    for (const s of house.walls || []) {
      walls.append(svg("line", { class: "wall", x1: X(s.x0), y1: Y(s.y0), x2: X(s.x1), y2: Y(s.y1) }));
    }
    for (const d of house.doors || []) {
      walls.append(svg("line", { class: "door", "data-door": d.name, x1: X(d.x0), y1: Y(d.y0), x2: X(d.x1), y2: Y(d.y1) },
                       svg("title", { text: d.name })));
    }
    for (const wp of house.waypoints || []) {
      const s = 0.12, tags = wp.tags || [];
      waypoints.append(svg("g", { class: "waypoint", "data-waypoint": wp.name, "data-tags": tags.join(" "),
                                  "data-office": tags.includes("office"),
                                  transform: `translate(${X(wp.x)} ${Y(wp.y)})` },
                           svg("path", { d: `M${-s} ${-s}L${s} ${s}M${-s} ${s}L${s} ${-s}` }),
                           svg("text", { x: 0.12, y: -0.08, text: wp.name }),
                           svg("title", { text: wp.name + (tags.length ? " [" + tags.join(", ") + "]" : "") })));
    }
    map.append(svg("g", { class: "layer-tracks", id: "fleet-tracks" }), svg("g", { class: "layer-robots", id: "fleet-robots" }));
  }

  function renderMap(m) {
    const X = view.X, Y = view.Y;
    const tracks = $("#fleet-tracks"), robots = $("#fleet-robots");
    if (!tracks) return;
    tracks.replaceChildren();
    robots.replaceChildren();
    for (const r of m.robots.values()) {
      if (r.track.length > 1) {
        tracks.append(svg("polyline", { class: "fleet-track", "data-track": r.id, stroke: r.color,
                                        points: r.track.map((p) => X(p[0]) + "," + Y(p[1])).join(" ") }));
      }
      if (r.x === null) continue;
      const label = r.alive ? (r.stage ? `${r.task} ${r.stage}` : "") : "killed";
      robots.append(svg("g", { class: "fleet-robot", "data-robot": r.id, "data-alive": r.alive, "data-moving": r.moving,
                               "data-task": r.task, "data-stage": r.stage,
                               transform: `translate(${X(r.x)} ${Y(r.y)})` },
                        svg("circle", { r: 0.45, fill: r.color }),
                        svg("text", { x: 0.55, y: 0.1, text: r.id }),
                        svg("text", { class: "stage", x: 0.55, y: 0.55, text: label }),
                        svg("title", { text: `${r.id}${r.alive ? "" : " (" + r.killed + ")"}: ${label || "idle"}` })));
    }
  }

  function renderRobots(m) {
    const body = $("#robots tbody");
    body.replaceChildren(...[...m.robots.values()].map((r) =>
      el("tr", { "data-robot": r.id, "data-alive": r.alive, "data-stage": r.stage, "data-task": r.task },
         el("td", {}, el("span", { style: `color:${r.color}`, text: "● " }), r.id),
         el("td", { text: r.task ? `${r.task} #${r.round}` : "" }),
         el("td", { text: r.stage }),
         el("td", { text: r.distance ? r.distance.toFixed(1) + " m" : "" }),
         el("td", { text: r.alive ? (r.moving ? "moving" : "") : r.killed }))));
    const nb = $("#neighbors tbody");
    nb.replaceChildren(...[...m.neighbors.entries()].sort(([a], [b]) => a.localeCompare(b)).map(([agent, table]) =>
      el("tr", { "data-agent": agent, "data-count": table.size },
         el("td", { text: agent }),
         el("td", {}, ...[...table.entries()].sort(([a], [b]) => a.localeCompare(b)).map(([n, role]) =>
           el("span", { class: "neighbor", "data-neighbor": n, "data-role": role, text: n }))))));
  }

  function renderAuctions(m) {
    const box = $("#auctions");
    box.replaceChildren(...[...m.tasks.values()].map((t) => {
      const outcome = t.outcome === "running" ? "running" : `${t.outcome} by ${t.robot}` + (t.detail ? ` (${t.detail})` : "");
      const rounds = [...t.rounds.values()].sort((a, b) => a.round - b.round).map((r) => {
        const bids = [...r.bids.entries()].sort((a, b) => a[1] - b[1]).map(([id, c]) =>
          el("li", { class: id === r.winner ? "winner" : "", "data-bid": id, "data-cost": c, text: `${id} ${cost(c)}` }));
        const late = [...r.late.entries()].map(([id, c]) =>
          el("li", { class: "late", "data-late-bid": id, "data-cost": c, text: `${id} ${cost(c)} (late)` }));
        const declined = [...r.declined.entries()].sort(([a], [b]) => a.localeCompare(b)).map(([id, why]) =>
          el("li", { class: "declined", "data-declined": id, text: `${id} declined: ${why}` }));
        const attrs = { class: "round", "data-task": t.task, "data-round": r.round, "data-state": r.state,
                        "data-winner": r.winner };
        if (r.reauction !== null) attrs["data-reauction"] = r.reauction;
        return el("div", attrs,
                  el("div", {}, el("b", { text: `round ${r.round}` }),
                     r.winner ? ` — ${r.winner} won at ${cost(r.cost)} m${r.assigned ? ", acknowledged" : ""}` : " — bidding",
                     r.excluded.length ? ` (without ${r.excluded.join(", ")})` : ""),
                  r.reauction !== null ? el("div", { class: "reason", text: "auctioned again: " + r.reauction }) : null,
                  el("ul", {}, ...bids, ...late, ...declined),
                  r.endedBy ? el("div", { class: "reason", "data-ended-by": r.endedBy, text: "ended: " + r.endedBy }) : null);
      });
      const stages = t.stages.map((s) => `${s.robot} ${s.stage}`).join(" → ");
      return el("section", { class: "task", "data-task": t.task, "data-pickup": t.pickup, "data-dropoff": t.dropoff,
                             "data-outcome": t.outcome, "data-robot": t.robot, "data-rounds": t.rounds.size },
                el("h3", {}, `${t.task}: ${t.pickup} → ${t.dropoff} `, el("span", { class: "outcome", text: outcome })),
                ...rounds,
                stages ? el("div", { class: "stages", text: stages }) : null);
    }));
  }

  function renderLog(m) {
    $("#log").replaceChildren(...m.log.slice().reverse().map((r) =>
      el("li", { "data-kind": r.kind, "data-source": r.source || "", "data-event": r.event || "" },
         el("span", { class: "t", text: r.time || "" }), el("span", { class: "src", text: r.source || "" }), r.text || "")));
  }

  function renderNow() {
    view.pending = false;
    const m = view.model;
    $("#clock").textContent = m.lastTime || "—";
    const plan = m.plan;
    $("#plan").textContent = plan ? `· ${plan.text}${plan.kill ? " · kill " + plan.kill : ""}` : "";
    const summary = $("#summary");
    summary.dataset.success = m.summary ? String(m.summary.success) : "";
    summary.textContent = m.summary ? m.summary.text : "running";
    const c = $("#connection");
    c.dataset.state = view.connection;
    c.textContent = view.connection;
    renderMap(m);
    renderRobots(m);
    renderAuctions(m);
    renderLog(m);
  }

  function render() {
    if (view.pending) return;
    view.pending = true;
    requestAnimationFrame(renderNow);
  }

  // ---------------------------------------------------------------- the feed

  let buffered = [];   // records that came before the snapshot
  let loaded = false;

  async function loadSnapshot() {
    loaded = false;
    const res = await fetch("/api/snapshot");
    if (!res.ok) throw new Error(`/api/snapshot answered ${res.status}`);
    const s = await res.json();
    view.snapshot = s;
    view.model = newModel();
    $("#house-name").textContent = s.house ? s.house.name || "" : "";
    buildMap(s.house);
    for (const r of s.records || []) fold(view.model, r);
    for (const r of buffered) fold(view.model, r);
    buffered = [];
    loaded = true;
    render();
  }

  function connect() {
    const events = new EventSource("/api/events");
    events.addEventListener("open", () => {
      view.connection = "live";
      loadSnapshot().catch((e) => console.error("dashboard: " + e.message));
    });
    events.addEventListener("record", (e) => {
      const rec = JSON.parse(e.data);
      if (loaded) { fold(view.model, rec); render(); } else buffered.push(rec);
    });
    events.addEventListener("dropped", () => loadSnapshot().catch((e) => console.error("dashboard: " + e.message)));
    events.addEventListener("error", () => {
      // The run ended (the server stopped) or the link broke: EventSource reconnects by itself.
      view.connection = "disconnected";
      render();
    });
  }

  window.icarsDashboard = { get model() { return view.model; }, renderNow, snapshot: () => view.snapshot };
  connect();
})();
