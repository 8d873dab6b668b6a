// The dashboard's model: what the house, the statechart and the behavior trees look like at one
// point of a run, folded from trace records (docs/trace.md) one at a time. No DOM here: app.js
// renders a Model, and replay keeps clones of it as checkpoints.
//
// A Model is built from the /api/snapshot object (its house, policy and services; the structure
// is shared, never changed) and then only changes through apply(record), setServices(list) and
// clone(). Folding the same records into the same snapshot always gives the same model.
(function (root) {
  "use strict";

  const TRACK_POINTS = 200;       // the robots' recent track
  const TRANSITION_LOG = 50;      // the transition log, newest last
  const TARGET_PATTERN = /^\(\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\)$/;

  // The static part of a model, computed once per snapshot and shared by every clone.
  class Structure {
    constructor(snapshot) {
      const house = snapshot.house || {};
      const policy = snapshot.policy || {};
      this.house = house;
      this.policy = policy;
      this.policyName = policy.name || "";
      this.places = new Map();      // waypoint, room or furniture name -> {x, y}
      for (const r of house.rooms || []) this.places.set(r.name, centre(r));
      for (const f of house.furniture || []) this.places.set(f.name, centre(f));
      for (const w of house.waypoints || []) this.places.set(w.name, { x: w.x, y: w.y });
      this.carriers = new Map();    // device id -> robot id ("" for a static device)
      for (const d of house.devices || []) this.carriers.set(d.id, d.carrier || "");

      // The statechart: every state by name with its parent, in document order.
      this.states = [];             // {name, kind, task, parent, depth}
      this.stateByName = new Map();
      this.statesOfTask = new Map(); // task -> [state names]
      const visit = (node, parent, depth) => {
        const s = { name: node.name, kind: node.kind || "state", task: node.task || "", parent, depth };
        this.states.push(s);
        this.stateByName.set(s.name, s);
        if (s.task) {
          if (!this.statesOfTask.has(s.task)) this.statesOfTask.set(s.task, []);
          this.statesOfTask.get(s.task).push(s.name);
        }
        for (const c of node.children || []) visit(c, s.name, depth + 1);
      };
      if (policy.statechart) visit(policy.statechart, null, 0);
      this.chartName = policy.statechart ? policy.statechart.name : "";

      // The behavior trees: every node's path, "<task>/<root>/.../<node>" as the trace writes it.
      this.nodePaths = new Map();   // path -> {task, name, type}
      this.taskRoots = new Map();   // task -> path of its root node
      for (const [task, rootNode] of Object.entries(policy.tasks || {})) {
        const walk = (node, prefix) => {
          const path = prefix + "/" + nodeName(node);
          this.nodePaths.set(path, { task, name: nodeName(node), type: node.type || "" });
          for (const c of node.children || []) walk(c, path);
          return path;
        };
        if (rootNode) this.taskRoots.set(task, walk(rootNode, task));
      }
      this.resolved = new Map();    // a record's source -> node path, or null
    }

    // The tree node a record's source names: the exact path, else the known path of the same
    // task that ends with the longest suffix of the source (a server that writes the paths
    // slightly differently still lights the right node); null when none matches.
    resolveNode(source) {
      if (this.resolved.has(source)) return this.resolved.get(source);
      let found = this.nodePaths.has(source) ? source : null;
      if (!found) {
        const parts = source.split("/");
        for (let cut = 1; cut < parts.length && !found; ++cut) {
          const suffix = "/" + parts.slice(cut).join("/");
          let sameTask = null, other = null;
          for (const [path, info] of this.nodePaths) {
            if (!path.endsWith(suffix)) continue;
            if (info.task === parts[0]) { sameTask = path; break; }
            if (other === null) other = path;
          }
          found = sameTask || other;
        }
      }
      this.resolved.set(source, found);
      return found;
    }

    // Where a wheels target (`dock`, `bedroom`, `(1.60, 4.50)`) is, or null.
    locate(target) {
      const m = TARGET_PATTERN.exec(String(target).trim());
      if (m) return { x: parseFloat(m[1]), y: parseFloat(m[2]) };
      return this.places.get(target) || null;
    }

    // The state with its ancestors, outermost first (the statechart's root left out).
    lineage(name) {
      const out = [];
      for (let s = this.stateByName.get(name); s && s.parent !== null; s = this.stateByName.get(s.parent)) {
        out.unshift(s.name);
      }
      return out;
    }
  }

  function centre(r) { return { x: (r.x0 + r.x1) / 2, y: (r.y0 + r.y1) / 2 }; }
  function nodeName(n) { return n.name || n.type || "?"; }

  class Model {
    // snapshot: the /api/snapshot object (its records are not applied: the caller folds them).
    constructor(snapshot, structure) {
      if (!snapshot && !structure) return;   // clone() fills the fields itself
      this.structure = structure || new Structure(snapshot);
      const house = this.structure.house;
      this.t = null;            // time of the latest record, ms
      this.count = 0;           // records applied
      this.lastIndex = -1;      // the latest record's `index`, when records carry one
      this.policyName = this.structure.policyName;
      this.policyRunning = false;
      this.partial = false;     // set by the caller when the first records of the run are missing
      this.robots = {};
      for (const r of house.robots || []) {
        this.robots[r.id] = { x: r.x, y: r.y, heading: r.theta ?? null, moving: false, track: [],
                              target: null, radius: r.radius || 0.25 };
      }
      this.users = {};
      for (const u of house.users || []) {
        this.users[u.id] = { x: u.x, y: u.y, room: "", posture: "standing", furniture: "", radius: u.radius || 0.2 };
      }
      this.devices = {};        // id -> {on, channel, volume, intensity, playing, spoke, lost, t}
      for (const d of house.devices || []) this.devices[d.id] = { lost: false };
      this.active = {};         // state name -> true
      this.tasks = {};          // task -> {status: running|stopped|failure, reason, t}
      this.nodes = {};          // node path -> {status: running|succeeded|failed|halted, reason, t}
      this.nodeLast = {};       // node path -> {kind, text, t}: the last event, note or call there
      this.services = {};       // id -> service object (with `available`)
      for (const s of snapshot ? snapshot.services || [] : []) this.services[s.id] = Object.assign({}, s);
      this.transitions = [];    // the last transition records, oldest first
      this.policyChanged = null; // a policy record naming another policy than the structure's
    }

    clone() {
      const m = new Model();
      m.structure = this.structure;
      for (const key of ["t", "count", "lastIndex", "policyName", "policyRunning", "partial", "policyChanged"]) {
        m[key] = this[key];
      }
      m.robots = {};
      for (const [id, r] of Object.entries(this.robots)) {
        m.robots[id] = Object.assign({}, r, { track: r.track.slice(), target: r.target && Object.assign({}, r.target) });
      }
      m.users = copyRecords(this.users);
      m.devices = copyRecords(this.devices);
      m.active = Object.assign({}, this.active);
      m.tasks = copyRecords(this.tasks);
      m.nodes = copyRecords(this.nodes);
      m.nodeLast = copyRecords(this.nodeLast);
      m.services = copyRecords(this.services);
      m.transitions = this.transitions.slice();
      return m;
    }

    // Active states in document order, the statechart's root left out.
    activeStates() {
      return this.structure.states.filter((s) => s.parent !== null && this.active[s.name]).map((s) => s.name);
    }

    runningTasks() {
      return Object.keys(this.tasks).filter((t) => this.tasks[t].status === "running");
    }

    // The services as received, with availability updated by device records.
    setServices(list) {
      this.services = {};
      for (const s of list || []) this.services[s.id] = Object.assign({}, s);
    }

    apply(r) {
      this.count += 1;
      if (typeof r.index === "number") this.lastIndex = r.index;
      if (typeof r.t === "number" && (this.t === null || r.t > this.t)) this.t = r.t;
      const handler = HANDLERS[r.kind];
      if (handler) handler(this, r);
      return this;
    }

    // With `partial`, records of a task that no `task` record started yet mark it (and the
    // states that run it) active: the run's beginning is missing, not the task.
    inferTask(task) {
      if (!this.partial || !task || this.tasks[task]) return;
      if (!this.structure.taskRoots.has(task)) return;
      this.tasks[task] = { status: "running", reason: "", t: this.t, inferred: true };
      for (const state of this.structure.statesOfTask.get(task) || []) {
        for (const s of this.structure.lineage(state)) this.active[s] = true;
      }
      this.policyRunning = true;
    }

    setNodeLast(path, r) {
      this.nodeLast[path] = { kind: r.kind, text: shortText(r, path), t: r.t };
    }
  }

  function copyRecords(obj) {
    const out = {};
    for (const [k, v] of Object.entries(obj)) out[k] = Object.assign({}, v);
    return out;
  }

  // The text of a record without the node path it starts with.
  function shortText(r, path) {
    let text = r.text || "";
    for (const prefix of [r.source + ": ", r.source + " ", path + ": "]) {
      if (text.startsWith(prefix)) { text = text.slice(prefix.length); break; }
    }
    return text;
  }

  const BEHAVIOR_STATUS = { start: "running", success: "succeeded", failure: "failed", halt: "halted" };

  const HANDLERS = {
    policy(m, r) {
      const started = /started$/.test(r.text || "");
      m.active = {};
      for (const t of Object.keys(m.tasks)) {
        if (m.tasks[t].status === "running") m.tasks[t] = { status: "stopped", reason: "", t: r.t };
      }
      m.policyRunning = started;
      if (started) {
        m.tasks = {};
        m.nodes = {};
        m.nodeLast = {};
        m.partial = false;
      }
      if (r.policy) {
        m.policyName = r.policy;
        if (r.policy !== m.structure.policyName) m.policyChanged = r.policy;
      }
    },

    state(m, r) {
      if (r.event === "enter") m.active[r.state] = true;
      else if (r.event === "exit") delete m.active[r.state];
      m.policyRunning = true;
    },

    task(m, r) {
      if (r.event === "start") {
        m.tasks[r.task] = { status: "running", reason: "", t: r.t };
        const prefix = r.task + "/";
        for (const path of Object.keys(m.nodes)) if (path.startsWith(prefix)) delete m.nodes[path];
        for (const path of Object.keys(m.nodeLast)) if (path.startsWith(prefix)) delete m.nodeLast[path];
      } else if (r.event === "stop") {
        m.tasks[r.task] = { status: "stopped", reason: "", t: r.t };
      } else if (r.event === "failure") {
        m.tasks[r.task] = { status: "failure", reason: r.reason || "", t: r.t };
      }
    },

    transition(m, r) {
      m.transitions.push({ t: r.t, time: r.time, from: r.from, to: r.to, event: r.event,
                           declared_in: r.declared_in, text: r.text });
      if (m.transitions.length > TRANSITION_LOG) m.transitions.splice(0, m.transitions.length - TRANSITION_LOG);
    },

    behavior(m, r) {
      const path = m.structure.resolveNode(r.source) || r.source;
      m.inferTask(path.split("/")[0]);
      const status = BEHAVIOR_STATUS[r.event];
      if (status) m.nodes[path] = { status, reason: r.reason || "", t: r.t };
    },

    event(m, r) {
      // The task writes the events its root propagates: they belong to the root node.
      const task = r.task || r.source;
      m.inferTask(task);
      const path = m.structure.taskRoots.get(task) || m.structure.resolveNode(r.source);
      if (path) m.nodeLast[path] = { kind: "event", text: eventText(r), t: r.t };
    },

    note(m, r) {
      const path = m.structure.resolveNode(r.source);
      if (path) m.setNodeLast(path, r);
    },

    call(m, r) {
      const path = m.structure.resolveNode(r.source);
      if (path) {
        m.inferTask(path.split("/")[0]);
        m.setNodeLast(path, r);
      }
    },

    device(m, r) {
      const lost = r.event === "DeviceLost" || r.event === "DeviceForgotten";
      const back = r.event === "DeviceBack" || r.event === "DeviceRestored";
      if (!lost && !back) return;
      if (m.devices[r.device]) m.devices[r.device] = Object.assign({}, m.devices[r.device], { lost });
      else m.devices[r.device] = { lost };
      for (const [id, s] of Object.entries(m.services)) {
        if (s.device === r.device) m.services[id] = Object.assign({}, s, { available: back });
      }
    },

    effect(m, r) {
      const d = Object.assign({}, m.devices[r.device] || { lost: false });
      d.t = r.t;
      switch (r.what) {
        case "power": d.on = r.value === "on"; break;
        case "channel": d.channel = r.value; break;
        case "volume": d.volume = r.value; break;
        case "intensity": d.intensity = r.value; break;
        case "playing": d.playing = r.value; break;
        case "stopped": d.playing = ""; break;
        case "spoke": d.spoke = r.value; break;
        default: break;
      }
      m.devices[r.device] = d;
      const robotId = m.structure.carriers.get(r.device);
      const robot = robotId && m.robots[robotId];
      if (!robot) return;
      if (r.what === "going_to" || r.what === "heading") {
        const at = m.structure.locate(r.value);
        robot.target = { label: r.value, x: at ? at.x : null, y: at ? at.y : null, t: r.t };
      } else if (r.what === "halted") {
        robot.target = null;
      } else if (r.what === "turned") {
        const a = parseFloat(r.value);
        if (!Number.isNaN(a)) robot.heading = a;
      }
    },

    robot(m, r) {
      let robot = m.robots[r.robot];
      if (!robot) robot = m.robots[r.robot] = { x: r.x, y: r.y, heading: null, moving: false, track: [], target: null, radius: 0.25 };
      const dx = r.x - robot.x, dy = r.y - robot.y;
      if (dx * dx + dy * dy > 1e-6) robot.heading = Math.atan2(dy, dx);
      robot.x = r.x;
      robot.y = r.y;
      robot.moving = !!r.moving;
      robot.track.push([r.x, r.y]);
      if (robot.track.length > TRACK_POINTS + 50) robot.track.splice(0, robot.track.length - TRACK_POINTS);
      if (!robot.moving && robot.target && r.t > robot.target.t) robot.target = null;
    },

    user(m, r) {
      m.users[r.user] = Object.assign({}, m.users[r.user] || { radius: 0.2 },
        { x: r.x, y: r.y, room: r.room || "", posture: r.posture || "", furniture: r.furniture || "" });
    },
  };

  function eventText(r) {
    const props = r.properties || {};
    const parts = Object.keys(props).filter((k) => k !== "time_ms").map((k) => k + "=" + formatValue(props[k]));
    return r.event + (parts.length ? " " + parts.join(" ") : "");
  }

  function formatValue(v) {
    if (typeof v === "number" && !Number.isInteger(v)) return String(Math.round(v * 100) / 100);
    return String(v);
  }

  // `d<day> HH:MM:SS[.mmm]` as the trace writes `time`.
  function formatTime(ms, withMillis) {
    if (ms === null || ms === undefined || Number.isNaN(ms)) return "—";
    const day = Math.floor(ms / 86400000);
    let rest = ms - day * 86400000;
    const h = Math.floor(rest / 3600000); rest -= h * 3600000;
    const min = Math.floor(rest / 60000); rest -= min * 60000;
    const s = Math.floor(rest / 1000);
    const milli = Math.floor(rest - s * 1000);
    const pad = (n, w) => String(n).padStart(w || 2, "0");
    let out = "d" + day + " " + pad(h) + ":" + pad(min) + ":" + pad(s);
    if (withMillis && milli) out += "." + pad(milli, 3);
    return out;
  }

  const api = { Model, Structure, formatTime, TRACK_POINTS, TRANSITION_LOG };
  if (typeof module !== "undefined" && module.exports) module.exports = api;
  else root.IcarsModel = api;
})(typeof self !== "undefined" ? self : this);
