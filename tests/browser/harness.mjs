// What every browser test of the dashboard shares: its command line, an `icars` child process
// with its dashboard address, Debian's chromium driven headless through puppeteer-core, waits on
// what the page shows (bounded, never a fixed sleep), screenshots, and a clean end — the browser
// closed and icars killed whether the test passed, failed or was interrupted.
//
// A test is `runTest(name, async (t) => { ... })`; it passes when its body returns and fails
// (exit 1, with the reason and the tail of icars's output) when the body throws, a wait times out,
// the page throws a JavaScript error or icars exits before the test is done.

import { spawn } from "node:child_process";
import { existsSync, mkdtempSync, mkdirSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import path from "node:path";

export const WAIT_MS = 60_000;   // the bound of every wait on the page or on icars
const TEST_MS = 240_000;         // the whole test, below ctest's TIMEOUT of 300 s

// --icars BINARY --source DIR [--out DIR] [--chromium BINARY]; --out is where screenshots go
// (default: icars-browser-screenshots in the temporary directory).
export function parseArgs(argv) {
  const args = { chromium: process.env.ICARS_CHROMIUM || "/usr/bin/chromium", out: "" };
  for (let i = 0; i < argv.length; ++i) {
    const key = argv[i];
    if (!key.startsWith("--") || i + 1 >= argv.length) throw new Error(`bad argument '${key}'`);
    args[key.slice(2)] = argv[++i];
  }
  for (const required of ["icars", "source"]) {
    if (!args[required]) throw new Error(`--${required} is required (usage: --icars BINARY --source DIR [--out DIR])`);
  }
  return args;
}

// Simulated time of a record or of the page's `#clock` text ("d0 18:10:22" or "d1 07:00:09.545")
// in ms since day 0's midnight, the unit of records' `t`.
export function parseClock(text) {
  const m = /^d(\d+) (\d\d):(\d\d)(?::(\d\d)(?:\.(\d+))?)?/.exec(text.trim());
  if (!m) return null;
  const [, d, h, min, s = "0", frac = "0"] = m;
  return ((Number(d) * 24 + Number(h)) * 60 + Number(min)) * 60_000 + Number(s) * 1000 + Number(frac.padEnd(3, "0").slice(0, 3));
}

export const at = (hhmm, day = 0) => parseClock(`d${day} ${hhmm}`);

class Icars {
  constructor(binary, args, cwd) {
    this.output = "";
    this.exited = null;
    this.stopping = false;
    this.proc = spawn(binary, args, { cwd, stdio: ["ignore", "pipe", "pipe"] });
    this.exit = new Promise((resolve) => {
      this.proc.on("exit", (code, signal) => { this.exited = { code, signal }; resolve(this.exited); });
      this.proc.on("error", (e) => { this.output += `\n${binary}: ${e.message}\n`; this.exited = { code: -1 }; resolve(this.exited); });
    });
    this.proc.stdout.on("data", (d) => { this.output += d; });
    this.proc.stderr.on("data", (d) => { this.output += d; });
  }

  // Resolves with the first match of `pattern` in icars's output; rejects when icars exits first.
  async waitForOutput(pattern, what) {
    const deadline = Date.now() + WAIT_MS;
    for (;;) {
      const m = pattern.exec(this.output);
      if (m) return m;
      if (this.exited) throw new Error(`icars exited (${describeExit(this.exited)}) before printing ${what}`);
      if (Date.now() > deadline) throw new Error(`icars printed no ${what} within ${WAIT_MS / 1000} s`);
      await Promise.race([this.exit, new Promise((r) => setTimeout(r, 50))]);
    }
  }

  // SIGTERM, then SIGKILL if it is still there after 10 s.
  async stop() {
    this.stopping = true;
    if (this.exited) return;
    this.proc.kill("SIGTERM");
    const timer = setTimeout(() => { if (!this.exited) this.proc.kill("SIGKILL"); }, 10_000);
    await this.exit;
    clearTimeout(timer);
  }

  tail(lines = 30) {
    return this.output.trimEnd().split("\n").slice(-lines).join("\n");
  }
}

function describeExit(e) {
  return e.signal ? `signal ${e.signal}` : `exit code ${e.code}`;
}

class TestContext {
  constructor(name, args) {
    this.name = name;
    this.args = args;
    this.source = path.resolve(args.source);
    this.tmp = mkdtempSync(path.join(tmpdir(), `icars-${name}-`));
    this.out = path.resolve(args.out || path.join(tmpdir(), "icars-browser-screenshots"));
    mkdirSync(this.out, { recursive: true });
    this.processes = [];
    this.browser = null;
    this.pageErrors = [];
    // Rejects at the first JavaScript error on the page or exit of a dashboard's icars: every wait
    // races it, so that the test fails at once instead of at the end of a wait.
    this.brokenBy = null;
    this.broken = new Promise((_, reject) => {
      this.breaks = (e) => { this.brokenBy = this.brokenBy || e; reject(this.brokenBy); };
    });
    this.broken.catch(() => {});
  }

  src(relative) { return path.join(this.source, relative); }

  log(message) { console.log(`[${this.name}] ${message}`); }

  // Runs `icars ARGS...` (or `icars-coros ARGS...`, given as --icars) from the source tree and
  // waits for its dashboard line. Returns the process, the page's address (with the token for
  // `run`; /fleet for icars-coros) and the token.
  async startIcars(args) {
    // Chromium first: on a loaded machine it takes seconds to start, and a run started before it
    // would be seconds further along when the page opens than the test expects.
    await this.launchBrowser();
    const icars = new Icars(path.resolve(this.args.icars), args, this.source);
    this.processes.push(icars);
    this.log(`icars ${args.join(" ")}`);
    const m = await icars.waitForOutput(/\[icars(?:-coros)?\] (?:dashboard|replaying [^\n]*): (http:\/\/127\.0\.0\.1:(\d+)\/(?:fleet)?(?:\?token=(\w+))?)/,
                                        "its dashboard address");
    icars.url = m[1];
    icars.port = Number(m[2]);
    icars.token = m[3] || "";
    icars.exit.then((e) => {
      if (!icars.stopping) this.breaks(new Error(`icars exited (${describeExit(e)}) while the page was open`));
    });
    this.log(`dashboard at http://127.0.0.1:${icars.port}/`);
    return icars;
  }

  // Runs `icars ARGS...` to its end (a recording run); fails on a non-zero exit.
  async runIcars(args) {
    const icars = new Icars(path.resolve(this.args.icars), args, this.source);
    this.processes.push(icars);
    this.log(`icars ${args.join(" ")}`);
    const timer = setTimeout(() => icars.proc.kill("SIGKILL"), WAIT_MS);
    const e = await icars.exit;
    clearTimeout(timer);
    if (e.code !== 0) throw new Error(`icars ${args[0]} failed (${describeExit(e)})`);
    return icars;
  }

  // Headless chromium, started once per test.
  async launchBrowser() {
    if (this.browser) return;
    if (!existsSync(this.args.chromium)) {
      throw new Error(`no chromium at ${this.args.chromium}: run scripts/install-deps.sh (or give --chromium BINARY)`);
    }
    const started = Date.now();
    this.browser = await this.puppeteer.launch({
      executablePath: this.args.chromium,
      headless: true,
      // As root (CI) chromium needs --no-sandbox; the page is the project's own, from loopback.
      args: ["--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu", "--no-first-run"],
      defaultViewport: { width: 1600, height: 1000 },
      timeout: WAIT_MS,
    });
    this.log(`chromium up (${((Date.now() - started) / 1000).toFixed(1)} s)`);
  }

  // A page of headless chromium at `url`. A JavaScript error on the page, or a console error the
  // page's own code reports ("dashboard: ..."), fails the test.
  async openPage(url) {
    await this.launchBrowser();
    const page = await this.browser.newPage();
    page.setDefaultTimeout(WAIT_MS);
    const pageError = (message) => {
      this.pageErrors.push(message);
      this.breaks(new Error(this.pageErrors.join("\n")));
    };
    page.on("pageerror", (e) => pageError(`JavaScript error on the page: ${e.message}`));
    page.on("console", (m) => {
      if (m.type() === "error" && m.text().startsWith("dashboard:")) pageError(`the page reported: ${m.text()}`);
    });
    await page.goto(url, { waitUntil: "load" });
    this.page = page;
    return page;
  }

  checkPage() {
    if (this.brokenBy) throw this.brokenBy;
  }

  // Waits until `predicate` (run in the page, after rendering the model at once) returns a truthy
  // value, which it returns. `what` names the condition in the failure message, with `detail()`
  // (run in the page) telling what the page showed instead.
  async waitFor(what, predicate, arg, detail = () => ({
    clock: document.querySelector("#clock")?.textContent,
    active: document.querySelector("#active-states")?.textContent,
    connection: document.querySelector("#connection")?.textContent,
  })) {
    this.checkPage();
    const started = Date.now();
    try {
      const expression = `(() => {
        const d = window.icarsDashboard;
        if (d && d.model) d.renderNow();
        return (${predicate.toString()})(${JSON.stringify(arg ?? null)});
      })()`;
      const handle = await Promise.race([this.page.waitForFunction(expression, { polling: 50, timeout: WAIT_MS }),
                                         this.broken]);
      const value = await handle.jsonValue();
      await handle.dispose();
      this.checkPage();
      this.log(`${what} (${((Date.now() - started) / 1000).toFixed(1)} s)`);
      return value;
    } catch (e) {
      this.checkPage();
      let shown = "";
      try { shown = JSON.stringify(await this.page.evaluate(detail)); } catch { /* the page is gone */ }
      throw new Error(`the page did not show ${what} within ${WAIT_MS / 1000} s (${e.message.split("\n")[0]}); it showed ${shown}`);
    }
  }

  // Uses a control of the page as a user does: types `value` into `input` (when given), clicks
  // `button` and waits for the server's answer to `endpoint`. Returns the answer's status and body.
  async useControl(endpoint, button, input, value) {
    if (input) await this.page.locator(input).fill(String(value));
    const [response] = await Promise.race([Promise.all([
      this.page.waitForResponse((r) => new URL(r.url()).pathname === endpoint && r.request().method() === "POST",
                                { timeout: WAIT_MS }),
      this.page.click(button),
    ]), this.broken]);
    const body = await response.json().catch(() => null);
    this.log(`${endpoint} ${input ? JSON.stringify(String(value)) + " " : ""}-> ${response.status()} ${JSON.stringify(body)}`);
    return { status: response.status(), body };
  }

  // The speed box: `speed` simulated seconds per second from now on.
  async setSpeed(speed) {
    const answer = await this.useControl("/api/speed", "#speed-set", "#speed-value", speed);
    if (answer.status !== 200) throw new Error(`the speed control answered ${answer.status} ${JSON.stringify(answer.body)}`);
    await this.waitFor(`#speed-set's request marked ok`, () => document.querySelector("#speed-set")?.dataset.state === "ok");
  }

  async screenshot(file) {
    await this.page.evaluate(() => window.icarsDashboard && window.icarsDashboard.renderNow());
    const target = path.join(this.out, file);
    await this.page.screenshot({ path: target, fullPage: true });
    this.log(`screenshot ${target}`);
  }

  async close() {
    if (this.browser) await this.browser.close().catch(() => {});
    this.browser = null;
    await Promise.all(this.processes.map((p) => p.stop()));
    rmSync(this.tmp, { recursive: true, force: true });
  }
}

export async function runTest(name, body) {
  const started = Date.now();
  let t = null;
  let failed = null;
  let interrupted = false;
  const interrupt = async (signal) => {
    interrupted = true;
    console.error(`[${name}] FAILED: interrupted by ${signal}`);
    if (t) await t.close();
    process.exit(1);
  };
  process.on("SIGTERM", () => interrupt("SIGTERM"));
  process.on("SIGINT", () => interrupt("SIGINT"));
  const watchdog = setTimeout(() => {
    interrupted = true;
    console.error(`[${name}] FAILED: not done within ${TEST_MS / 1000} s`);
    (t ? t.close() : Promise.resolve()).finally(() => process.exit(1));
  }, TEST_MS);
  try {
    t = new TestContext(name, parseArgs(process.argv.slice(2)));
    try {
      t.puppeteer = (await import("puppeteer-core")).default;
    } catch (e) {
      throw new Error(`puppeteer-core is not installed in tests/browser (${e.message}): run scripts/install-deps.sh`);
    }
    await body(t);
    t.checkPage();
  } catch (e) {
    failed = e;
  }
  if (interrupted) return;   // interrupt() or the watchdog ends the process
  const logs = t ? t.processes.map((p) => p.tail()).filter((l) => l) : [];
  if (t) await t.close();
  clearTimeout(watchdog);
  const seconds = ((Date.now() - started) / 1000).toFixed(1);
  if (failed) {
    console.error(`[${name}] FAILED after ${seconds} s: ${failed.message}`);
    for (const l of logs) console.error(`--- icars's last output:\n${l}`);
    process.exit(1);
  }
  console.log(`[${name}] passed in ${seconds} s`);
  process.exit(0);
}
