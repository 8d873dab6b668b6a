// The fleet page of `icars-coros run --http` as a person watching the run sees it: three robots on
// the office floor, the delivery office_101 > office_112 auctioned; robot1 (the lowest bid from the
// docks, as in coros_scenario_test's re-auction test) wins round 1 and is killed on its way to the
// drop-off; the user auctions the task again once robot1's HELLOs stop, round 2 shows the reason
// and another winner, robot1 is marked dead, and the delivery finishes. The page loads without a
// JavaScript error; the map, the neighbour tables and the robots' tracks are drawn.
//
// node fleet_test.mjs --icars ICARS_COROS --agent ICARS_AGENT --source DIR [--out DIR]

import { runTest } from "./harness.mjs";

runTest("fleet", async (t) => {
  const args = [
    "run", "--map", t.src("houses/office_floor.xml"), "--robots", "3", "--deliveries", "office_101>office_112",
    "--kill", "robot1@to_dropoff", "--bid-window", "2000", "--neighbor-expiry", "3000", "--timeout", "120",
    "--http", "127.0.0.1:0", "--http-linger", "-1"];
  if (t.args.agent) args.push("--agent-bin", t.args.agent);
  const coros = await t.startIcars(args);
  await t.openPage(coros.url);
  const detail = () => ({
    clock: document.querySelector("#clock")?.textContent,
    connection: document.querySelector("#connection")?.dataset.state,
    auctions: document.querySelector("#auctions")?.innerText,
    robots: document.querySelector("#robots")?.innerText,
    neighbors: document.querySelector("#neighbors")?.innerText,
  });

  // The office floor: its rooms and the offices of the delivery, tagged.
  const snapshot = await (await fetch(`http://127.0.0.1:${coros.port}/api/snapshot`)).json();
  if (snapshot.mode !== "fleet") throw new Error(`the snapshot's mode is ${snapshot.mode}, not fleet`);
  const rooms = snapshot.house.rooms.map((r) => r.name);
  await t.waitFor(`the map with rooms ${rooms.join(", ")} and the offices`, (names) =>
    names.every((n) => document.querySelector(`#map [data-room="${n}"]`)) &&
    document.querySelector('#map [data-waypoint="office_101"][data-office="true"]') &&
    document.querySelector('#map [data-waypoint="office_112"][data-office="true"]'), rooms, detail);
  await t.waitFor("robot1..robot3 on the map", () =>
    ["robot1", "robot2", "robot3"].every((r) => document.querySelector(`#map .fleet-robot[data-robot="${r}"]`)),
    null, detail);

  // Discovery: every robot knows the two others and the user. A page that opens late may open after
  // robot1 was killed and its HELLOs expired; the tables then rightly no longer list it (robot1's
  // own table keeps what it last knew).
  await t.waitFor("each robot's neighbour table with the other robots and the user", () => {
    const robots = ["robot1", "robot2", "robot3"];
    const dead = (r) => document.querySelector(`#robots tr[data-robot="${r}"][data-alive="false"]`);
    return robots.every((r) => {
      const row = document.querySelector(`#neighbors tr[data-agent="${r}"]`);
      return row && row.querySelector('[data-neighbor="user"][data-role="user"]') &&
        !row.querySelector(`[data-neighbor="${r}"]`) &&
        robots.every((o) => o === r || dead(o) || row.querySelector(`[data-neighbor="${o}"][data-role="robot"]`));
    });
  }, null, detail);

  const task = await t.waitFor("round 1 won by robot1 with three bids", () => {
    const r = document.querySelector('.round[data-round="1"][data-winner="robot1"]');
    return r && r.querySelectorAll("[data-bid]").length === 3 && r.querySelector('li.winner[data-bid="robot1"]') &&
      r.dataset.task;
  }, null, detail);
  await t.waitFor("robot1 killed", () =>
    document.querySelector('#robots tr[data-robot="robot1"][data-alive="false"]') &&
    document.querySelector('#map .fleet-robot[data-robot="robot1"][data-alive="false"]'), null, detail);
  const second = await t.waitFor(`${task} auctioned again: round 2 with its reason and another winner`, (id) => {
    const r = document.querySelector(`.round[data-task="${id}"][data-round="2"][data-reauction]`);
    return r && r.dataset.winner && r.dataset.winner !== "robot1" && !r.querySelector('[data-bid="robot1"]') &&
      { winner: r.dataset.winner, reason: r.dataset.reauction, shown: r.querySelector(".reason").textContent };
  }, task, detail);
  t.log(`round 2: ${second.winner} won; ${second.shown}`);
  if (!/robot1/.test(second.reason)) throw new Error(`the re-auction's reason does not name robot1: ${second.reason}`);
  await t.waitFor(`round 1 marked as ended by the re-auction`, (id) =>
    document.querySelector(`.round[data-task="${id}"][data-round="1"][data-state="reauctioned"]`), task, detail);

  await t.waitFor(`${task} delivered by ${second.winner}`, ([id, winner]) => {
    const s = document.querySelector(`.task[data-task="${id}"]`);
    return s && s.dataset.outcome === "delivered" && s.dataset.robot === winner;
  }, [task, second.winner], detail);
  await t.waitFor("the run's summary: every delivery succeeded", () =>
    document.querySelector('#summary[data-success="true"]'), null, detail);
  await t.waitFor(`${second.winner}'s track drawn`, (winner) => {
    const line = document.querySelector(`#map .fleet-track[data-track="${winner}"]`);
    return line && line.getAttribute("points").split(" ").length > 5;
  }, second.winner, detail);
  await t.screenshot("dashboard-fleet.png");
});
