// Drives Debian's chromium through the map page of a running daemon (tests/map_browser.rs
// starts one replaying a fixture, then runs this):
//
//   node tests/browser/map.mjs http://127.0.0.1:PORT/ SCREENSHOT.png
//
// Checks, each a failure (exit 1) when it does not hold:
// - the page loads with no network: every request not to the daemon is blocked and counted,
//   and none may be made; no request fails, no script error is thrown;
// - the aircraft markers are exactly the tracks of /api/v1/tracks (same count, same ICAOs);
// - markers move on screen as events arrive;
// - clicking a marker opens its panel, titled with the callsign /api/v1/tracks/{icao} gives;
// and saves a screenshot. Prints one JSON line of what it measured.
import { chromium } from "playwright-core";

const url = process.argv[2];
const screenshot = process.argv[3] ?? "map.png";
if (!url) {
  console.error("usage: node map.mjs URL [SCREENSHOT.png]");
  process.exit(2);
}
const origin = new URL(url).origin;
const executablePath = process.env.CHROMIUM ?? "/usr/bin/chromium";

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const api = async (path) => {
  const r = await fetch(new URL(path, origin));
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return r.json();
};
/** Polls `f` until it returns a truthy value or `ms` pass; returns the last value. */
async function until(ms, f, every = 200) {
  const end = Date.now() + ms;
  let v;
  for (;;) {
    v = await f();
    if (v || Date.now() > end) return v;
    await sleep(every);
  }
}

const failures = [];
const check = (ok, what) => {
  if (!ok) failures.push(what);
  return ok;
};

const browser = await chromium.launch({
  executablePath,
  headless: true,
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"],
});
const result = {};
try {
  const context = await browser.newContext({ viewport: { width: 1440, height: 900 }, deviceScaleFactor: 1 });
  const page = await context.newPage();

  // No network: anything not addressed to the daemon is blocked and remembered.
  const offsite = [];
  const failed = [];
  const errors = [];
  let requests = 0;
  await context.route("**/*", (route) => {
    const u = new URL(route.request().url());
    if (u.origin === origin || u.protocol === "data:") return route.continue();
    offsite.push(u.href);
    return route.abort("blockedbyclient");
  });
  page.on("request", () => requests++);
  page.on("requestfailed", (r) => {
    // An event stream cut when the page closes is not a failure of the page.
    if (!r.url().includes("/api/v1/stream")) failed.push(`${r.url()}: ${r.failure()?.errorText}`);
  });
  page.on("response", (r) => {
    if (r.status() >= 400) failed.push(`${r.url()}: HTTP ${r.status()}`);
  });
  page.on("pageerror", (e) => errors.push(String(e)));
  page.on("console", (m) => {
    if (m.type() === "error") errors.push(m.text());
  });

  await page.goto(url, { waitUntil: "load" });
  const markerCount = () => page.evaluate(() => document.querySelectorAll(".ac-marker").length);
  check(await until(30000, async () => (await markerCount()) > 0), "no aircraft marker within 30 s");

  // The markers are the tracks the API lists. Both change as the replay runs, so compare
  // until they agree (a few hundred ms apart at most).
  let agree = null;
  await until(20000, async () => {
    const [icaos, listed] = await Promise.all([
      page.evaluate(() => [...document.querySelectorAll(".ac-marker")].map((e) => e.dataset.icao).sort()),
      api("api/v1/tracks"),
    ]);
    const want = listed.tracks.map((t) => t.icao).sort();
    agree = { markers: icaos.length, tracks: want.length, same: JSON.stringify(icaos) === JSON.stringify(want) };
    if (!agree.same) {
      agree.only_map = icaos.filter((i) => !want.includes(i)).slice(0, 5);
      agree.only_api = want.filter((i) => !icaos.includes(i)).slice(0, 5);
    }
    return agree.same;
  }, 300);
  Object.assign(result, agree);
  check(agree?.same, `markers and /api/v1/tracks differ: ${JSON.stringify(agree)}`);

  // Markers move on screen: the pixel positions of the airborne ones, now and a while later.
  const positions = () =>
    page.evaluate(() => {
      const out = {};
      for (const e of document.querySelectorAll(".ac-marker:not(.ground)")) {
        const r = e.getBoundingClientRect();
        out[e.dataset.icao] = [r.x, r.y];
      }
      return out;
    });
  const before = await positions();
  let moved = 0;
  await until(15000, async () => {
    const after = await positions();
    moved = Object.keys(before).filter(
      (i) => after[i] && Math.hypot(after[i][0] - before[i][0], after[i][1] - before[i][1]) >= 1,
    ).length;
    return moved >= Math.min(5, Object.keys(before).length) && moved > 0;
  }, 500);
  result.airborne = Object.keys(before).length;
  result.moved = moved;
  check(moved > 0, `no marker moved on screen in 15 s (${Object.keys(before).length} airborne)`);

  // Click a marker that has a callsign and is not covered by another one, as a user would.
  const listed = await api("api/v1/tracks");
  const named = new Map(listed.tracks.filter((t) => t.callsign).map((t) => [t.icao, t.callsign]));
  const target = await page.evaluate((icaos) => {
    for (const e of document.querySelectorAll(".ac-marker")) {
      if (!icaos.includes(e.dataset.icao)) continue;
      const r = e.getBoundingClientRect();
      const x = r.x + r.width / 2;
      const y = r.y + r.height / 2;
      if (x < 20 || y < 60 || x > innerWidth - 440 || y > innerHeight - 20) continue;
      const hit = document.elementFromPoint(x, y)?.closest(".ac-marker");
      if (hit === e) return e.dataset.icao;
    }
    return null;
  }, [...named.keys()]);
  check(target !== null, "no uncovered marker with a callsign to click");
  if (target) {
    await page.locator(`.ac-marker[data-icao="${target}"]`).click({ timeout: 5000 });
    await page.waitForSelector("#panel:not([hidden])", { timeout: 5000 });
    const title = (await page.textContent("#panel-title"))?.trim();
    const one = await api(`api/v1/tracks/${target}`);
    result.clicked = target;
    result.panel_title = title;
    result.callsign = one.callsign;
    check(title === one.callsign, `panel of ${target} says ${JSON.stringify(title)}, the API ${JSON.stringify(one.callsign)}`);
    const fields = await page.$$eval("#panel-body table.fields tr", (rows) => rows.length);
    result.panel_fields = fields;
    check(fields >= Object.keys(one).length - 1, `the panel lists ${fields} fields of ${Object.keys(one).length}`);
  }

  await sleep(500);
  await page.screenshot({ path: screenshot });
  result.screenshot = screenshot;
  result.requests = requests;
  result.offsite = offsite.length;
  result.failed = failed.length;
  result.errors = errors.length;
  check(offsite.length === 0, `requests off the daemon: ${offsite.slice(0, 5).join(", ")}`);
  check(failed.length === 0, `failed requests: ${failed.slice(0, 5).join(", ")}`);
  check(errors.length === 0, `page errors: ${errors.slice(0, 5).join(" | ")}`);
} catch (e) {
  failures.push(`error: ${e?.stack ?? e}`);
} finally {
  await browser.close();
}
console.log(JSON.stringify(result));
if (failures.length) {
  for (const f of failures) console.error(`FAIL: ${f}`);
  process.exit(1);
}
