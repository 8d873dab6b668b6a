// The say control: a sentence typed into the page reaches the house as the user's speech. In the
// paper evening the user sits down at 18:10 and asks for the TV at 18:12; slowed down once RestMode
// is active, the test says "turn on the TV" first, and the timeline shows the robot's microphone
// hearing it and the TV powering on before 18:12, and the map shows the TV on.

import { runTest, at, parseClock } from "./harness.mjs";

const SENTENCE = "turn on the TV";
const USERS_OWN_REQUEST = at("18:12");   // when the paper house's user asks for the TV

runTest("say", async (t) => {
  const icars = await t.startIcars([
    "run", t.src("examples/smart_home/paper_home.xml"), "--world", t.src("houses/paper_house.xml"),
    "--speed", "60", "--until", "07:30", "--quiet", "--http", "127.0.0.1:0"]);
  const page = await t.openPage(icars.url);
  await t.waitFor("the live connection and the controls", () =>
    document.querySelector("#connection").dataset.state === "live" && !document.querySelector("#controls").hidden);

  await t.waitFor("RestMode active", () => document.querySelector('[data-state="RestMode"]').classList.contains("active"));
  await t.setSpeed(2);
  await t.waitFor("the robot at the user (GoToUser succeeded)", () =>
    document.querySelector('[data-node="RestMode/Rest/VoiceControl/GoToUser"]').dataset.status === "succeeded");
  const tvBefore = await page.$eval('[data-device="tv"]', (e) => e.dataset.on ?? "unknown");
  if (tvBefore === "true") throw new Error("the TV is on before the test said anything");

  await page.select("#say-user", "user1");
  await page.type("#say-text", SENTENCE);
  const answer = await t.useControl("/api/say", "#say-send");
  if (answer.status !== 200 || answer.body?.said !== SENTENCE) {
    throw new Error(`the say control answered ${answer.status} ${JSON.stringify(answer.body)}`);
  }
  await t.waitFor("#say-send's request marked ok and the box emptied", () =>
    document.querySelector("#say-send").dataset.state === "ok" && document.querySelector("#say-text").value === "" &&
    document.querySelector("#say-error").hidden);

  // The timeline's rows: the microphone heard the sentence, then the TV powered on.
  const rowTime = (kind, source, needle) => t.waitFor(`${source}'s ${kind} row '${needle}' in the timeline`,
    ([k, s, n]) => {
      for (const li of document.querySelectorAll(`#timeline li[data-kind="${k}"][data-source="${s}"]`)) {
        if (li.textContent.includes(n)) return li.querySelector(".time").textContent;
      }
      return null;
    }, [kind, source, needle]);
  // Heard as the voice behaviors declare the phrase (VoiceTVControl: "turn on the tv").
  const heardAt = await rowTime("speech", "robot1_mic", `heard "${SENTENCE.toLowerCase()}"`);
  const poweredOnAt = await rowTime("effect", "tv", "tv: power on");
  t.log(`heard at ${heardAt}, the TV on at ${poweredOnAt}`);
  const heard = parseClock(heardAt);
  const poweredOn = parseClock(poweredOnAt);
  if (!(heard < USERS_OWN_REQUEST && poweredOn < USERS_OWN_REQUEST)) {
    throw new Error(`the TV came on at ${poweredOn} ms (heard at ${heard} ms), not before the user's own request at 18:12: ` +
                    "the run went too fast for the test to tell whose sentence it was");
  }
  await t.waitFor("the TV on on the map", () => document.querySelector('#map [data-device="tv"][data-on="true"]'));
  await t.screenshot("dashboard-say.png");
});
