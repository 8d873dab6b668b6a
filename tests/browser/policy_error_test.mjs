// The policy switch with a broken policy: loading `broken` (a policy whose tree names the unknown
// behavior type 'Wiat') from the page shows the server's located error, broken.xml's line and
// message, under the control; the running policy keeps running — the same states active, the
// clock going on, the connection live.

import { copyFileSync, mkdirSync } from "node:fs";
import path from "node:path";
import { runTest } from "./harness.mjs";

const EXPECTED = "broken.xml:4: error: unknown behavior type 'Wiat'";

runTest("policy_error", async (t) => {
  const policies = path.join(t.tmp, "policies");
  mkdirSync(policies);
  copyFileSync(t.src("examples/smart_home/paper_home.xml"), path.join(policies, "paper_home.xml"));
  copyFileSync(t.src("src/control/testdata/unknown_behavior.xml"), path.join(policies, "broken.xml"));

  const icars = await t.startIcars([
    "run", "paper_home", "--policies", policies, "--world", t.src("houses/paper_house.xml"),
    "--speed", "60", "--until", "07:30", "--quiet", "--http", "127.0.0.1:0"]);
  const page = await t.openPage(icars.url);
  await t.waitFor("the live connection and the controls", () =>
    document.querySelector("#connection").dataset.state === "live" && !document.querySelector("#controls").hidden);
  await t.waitFor("paper_home in the policy box", () => document.querySelector("#policy-name").value === "paper_home");
  await t.waitFor("RestMode active", () => document.querySelector('[data-state="RestMode"]').classList.contains("active"));
  const before = await page.$eval("#active-states", (e) => e.textContent);
  const recordsBefore = await page.evaluate(() => window.icarsDashboard.model.count);

  const answer = await t.useControl("/api/policy", "#policy-load", "#policy-name", "broken");
  if (answer.status !== 422) throw new Error(`POST /api/policy {"name": "broken"} answered ${answer.status}, not 422`);
  const shown = await t.waitFor("the error under the policy control", () => {
    const pre = document.querySelector("#policy-error");
    return !pre.hidden && document.querySelector("#policy-load").dataset.state === "error" && pre.textContent;
  });
  if (!shown.includes(EXPECTED)) throw new Error(`#policy-error shows '${shown}', without '${EXPECTED}'`);
  const errorBox = await page.$eval("#policy-error", (e) => ({ tag: e.tagName, visible: e.offsetHeight > 0 }));
  if (errorBox.tag !== "PRE" || !errorBox.visible) throw new Error(`#policy-error is not a visible <pre>: ${JSON.stringify(errorBox)}`);
  await t.screenshot("dashboard-policy-error.png");

  // The running policy goes on: the same states, new records (the run's clock), still live.
  await t.waitFor(`the states still '${before}', new records and the connection live`, ([states, count]) =>
    document.querySelector("#active-states").textContent === states &&
    document.querySelector('[data-state="paper_home"]').classList.contains("active") &&
    document.querySelector("#connection").dataset.state === "live" &&
    window.icarsDashboard.model.count > count + 20 &&
    window.icarsDashboard.snapshot.policy.name === "paper_home", [before, recordsBefore]);
  const snapshot = await (await fetch(`http://127.0.0.1:${icars.port}/api/snapshot`)).json();
  if (snapshot.policy?.name !== "paper_home") throw new Error(`the server runs ${JSON.stringify(snapshot.policy?.name)} now`);
});
