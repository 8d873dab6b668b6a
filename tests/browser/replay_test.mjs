// Replay: the paper night recorded with `icars run --trace` and shown by `icars replay --http`.
// The page is in replay mode with a time slider over the trace; moved as a user drags it, the
// slider shows SleepMode active at 22:45 and RestMode at 18:20 (going back in time), and the
// replay shows no controls.

import path from "node:path";
import { runTest, at, parseClock } from "./harness.mjs";

runTest("replay", async (t) => {
  const trace = path.join(t.tmp, "paper_night.jsonl");
  const policy = t.src("examples/smart_home/paper_home.xml");
  const world = t.src("houses/paper_house.xml");
  await t.runIcars(["run", policy, "--world", world, "--speed", "max", "--until", "07:30", "--quiet", "--trace", trace]);
  const icars = await t.startIcars(["replay", trace, "--world", world, "--policy", policy, "--http", "127.0.0.1:0"]);
  const page = await t.openPage(icars.url);

  const slider = await t.waitFor("the replay panel with its time slider", () => {
    const s = document.querySelector("#time-slider");
    return document.body.dataset.mode === "replay" && document.querySelector("#connection").dataset.state === "replay" &&
      !document.querySelector("#replay").hidden && document.querySelector("#controls").hidden &&
      Number(s.max) > Number(s.min) && { min: Number(s.min), max: Number(s.max) };
  });
  if (!(slider.min <= at("18:00") && slider.max >= at("07:00", 1))) {
    throw new Error(`the slider spans ${slider.min} to ${slider.max} ms, not the recorded evening and night`);
  }

  // Moves the slider as a drag does: a new value, then an `input` event.
  const moveSlider = async (hhmm) => {
    const value = at(hhmm);
    await page.$eval("#time-slider", (s, v) => {
      s.value = String(v);
      s.dispatchEvent(new Event("input", { bubbles: true }));
    }, value);
    await t.waitFor(`the view at ${hhmm}`, (v) => {
      const clock = document.querySelector("#replay-time").textContent;
      return clock.includes(" ") && Math.abs(window.icarsDashboard.viewTime - v) < 1000 && clock;
    }, value);
    const shown = parseClock(await page.$eval("#replay-time", (e) => e.textContent));
    if (shown !== value) throw new Error(`#replay-time shows ${shown} ms after moving the slider to ${value} ms (${hhmm})`);
  };

  await moveSlider("22:45");
  await t.waitFor("SleepMode active at 22:45", () =>
    document.querySelector('[data-state="SleepMode"]').classList.contains("active") &&
    !document.querySelector('[data-state="RestMode"]').classList.contains("active") &&
    document.querySelector("#active-states").textContent.split(", ").includes("SleepMode") &&
    document.querySelector('#transition-log li[data-to="SleepMode"]') &&
    document.querySelector('[data-user="user1"]').dataset.room === "bedroom");
  await t.screenshot("dashboard-replay-sleepmode.png");

  await moveSlider("18:20");
  await t.waitFor("RestMode active at 18:20", () =>
    document.querySelector('[data-state="RestMode"]').classList.contains("active") &&
    !document.querySelector('[data-state="SleepMode"]').classList.contains("active") &&
    document.querySelector("#active-states").textContent.split(", ").includes("RestMode") &&
    !document.querySelector('#transition-log li[data-to="SleepMode"]') &&
    document.querySelector('[data-user="user1"]').dataset.furniture === "sofa");
  await t.screenshot("dashboard-replay-restmode.png");
});
