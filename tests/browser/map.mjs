// Drives Debian's chromium through the map page of a running daemon (tests/map_browser.rs
// starts one replaying a fixture, then runs this):
//
//   node tests/browser/map.mjs http://127.0.0.1:PORT/ SCREENSHOT.png
//
// Checks, each a failure (exit 1) when it does not hold:
// - the page loads with no network: every request not to the daemon is blocked and counted,
//   and none may be made; no request fails, no script error is thrown;
// - the aircraft on the map are exactly the tracks of /api/v1/tracks (same ICAOs), every one
//   in view is drawn, and one of the 3x3 pixels at an icon's centre is its mode's colour;
// - they move on screen as events arrive;
// - clicking an aircraft opens its panel, titled with the callsign /api/v1/tracks/{icao}
//   gives, with every field, and the five mode probabilities;
// - after a network outage (every connection cut, then 503s), the page reconnects by
//   itself and drops the aircraft retired meanwhile (their events were lost);
// - once some of the first aircraft are retired, the map still shows exactly the tracks;
// - trails start from the history endpoint;
// and saves a screenshot. Prints one JSON line of what it measured.
//
// The aircraft are drawn on a canvas (src/api/web/map.js), so the page's state is read
// through window.adsbMap: its `drawn()` positions are those of the last drawing, and the
// pixels there are checked.
import net from "node:net";
import { chromium } from "playwright-core";

const daemonUrl = process.argv[2];
const screenshot = process.argv[3] ?? "map.png";
if (!daemonUrl) {
  console.error("usage: node map.mjs URL [SCREENSHOT.png]");
  process.exit(2);
}
const executablePath = process.env.CHROMIUM ?? "/usr/bin/chromium";

// The browser reaches the daemon through a TCP relay of ours, which can cut every
// connection and answer 503 for a while: a network outage, to see the page reconnect.
const daemon = new URL(daemonUrl);
const links = new Set();
let outage = false;
const relay = net.createServer((client) => {
  if (outage) {
    client.end("HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\ncontent-length: 2\r\nconnection: close\r\n\r\n{}");
    return;
  }
  const up = net.connect(Number(daemon.port), daemon.hostname);
  const link = [client, up];
  links.add(link);
  const close = () => {
    client.destroy();
    up.destroy();
    links.delete(link);
  };
  for (const s of link) {
    s.on("error", close);
    s.on("close", close);
  }
  client.pipe(up);
  up.pipe(client);
});
await new Promise((r) => relay.listen(0, "127.0.0.1", r));
const url = `http://127.0.0.1:${relay.address().port}/`;
const origin = new URL(url).origin;

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const api = async (path) => {
  const r = await fetch(new URL(path, daemon.origin));
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
    if (!r.url().includes("/api/v1/stream") && !outage) failed.push(`${r.url()}: ${r.failure()?.errorText}`);
  });
  // A trail asked for an aircraft retired since its last event is a 404 the page expects
  // (at 10x, 60 s of silence retires an aircraft within 6 s); counted apart.
  const isHistory = (u) => /\/api\/v1\/tracks\/[0-9a-f]{6}\/history$/.test(new URL(u).pathname);
  const history = { ok: 0, points: 0, gone: 0 };
  page.on("response", async (r) => {
    if (isHistory(r.url()) && r.status() === 404) history.gone++;
    else if (r.status() >= 400 && !outage) failed.push(`${r.url()}: HTTP ${r.status()}`);
    else if (isHistory(r.url()) && r.status() === 200) {
      history.ok++;
      history.points += (await r.json().catch(() => ({}))).points?.length ?? 0;
    }
  });
  page.on("pageerror", (e) => errors.push(String(e)));
  page.on("console", (m) => {
    // (Failed loads are reported as console errors too: judged above, by their response.)
    if (m.type() === "error" && !m.text().startsWith("Failed to load resource")) errors.push(m.text());
  });

  await page.goto(url, { waitUntil: "load" });
  const shown = () => page.evaluate(() => window.adsbMap?.icaos().sort() ?? []);
  check(await until(30000, async () => (await shown()).length > 0), "no aircraft on the map within 30 s");
  // The view fits itself to the aircraft once their first state is in.
  check(await until(10000, () => page.evaluate(() => window.adsbMap.settled())), "the view did not settle in 10 s");

  // The aircraft are the tracks the API lists. Both change as the replay runs, so compare
  // until they agree (a few hundred ms apart at most).
  async function agreeWithApi(ms) {
    let agree = null;
    await until(ms, async () => {
      const [icaos, listed] = await Promise.all([shown(), api("api/v1/tracks")]);
      const want = listed.tracks.map((t) => t.icao).sort();
      agree = { markers: icaos.length, tracks: want.length, same: JSON.stringify(icaos) === JSON.stringify(want), icaos };
      return agree.same;
    }, 300);
    if (!agree.same) {
      const want = (await api("api/v1/tracks")).tracks.map((t) => t.icao);
      agree.only_map = agree.icaos.filter((i) => !want.includes(i)).slice(0, 5);
      agree.only_api = want.filter((i) => !agree.icaos.includes(i)).slice(0, 5);
    }
    return agree;
  }
  const first = await agreeWithApi(20000);
  const firstIcaos = first.icaos;
  delete first.icaos;
  Object.assign(result, first);
  check(first.same, `aircraft on the map and /api/v1/tracks differ: ${JSON.stringify(first)}`);

  // Every aircraft well inside the view was drawn in the last drawing. Judged at a moment
  // when no drawing is due: an aircraft that arrived a few ms ago waits for the throttled
  // redraw (up to aircraft/10 ms), and that is the page working as designed.
  const undrawn = await page.evaluate(async () => {
    const m = window.adsbMap;
    const deadline = performance.now() + 5000;
    while (m.drawPending() && performance.now() < deadline) {
      await new Promise((r) => requestAnimationFrame(r));
    }
    const inner = m.map.getBounds().pad(-0.05);
    const drawn = m.drawn();
    return m.icaos().filter((i) => {
      const t = m.track(i);
      return inner.contains([t.lat, t.lon]) && !drawn[i];
    });
  });
  result.undrawn = undrawn.length;
  check(undrawn.length === 0, `aircraft in view not drawn: ${undrawn.slice(0, 5)}`);

  // Aircraft move on screen: the drawn positions of the airborne ones, now and a while later.
  const positions = () =>
    page.evaluate(() => {
      const m = window.adsbMap;
      return Object.fromEntries(Object.entries(m.drawn()).filter(([i]) => !m.track(i)?.on_ground));
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
  check(moved > 0, `no aircraft moved on screen in 15 s (${Object.keys(before).length} airborne)`);

  // Click an aircraft that has a callsign and stands apart (no other icon or label over it),
  // as a user would: the mouse at its icon's centre. Before that, the pixel there must be
  // its mode's colour: the icon is really drawn where the page says.
  const listed = await api("api/v1/tracks");
  const rank = { CT: 0, CA: 1, CHCA: 2, CH: 3, CV: 4 };
  const named = listed.tracks
    .filter((t) => t.callsign && !t.on_ground)
    .sort((a, b) => (rank[a.mode] ?? 5) - (rank[b.mode] ?? 5))
    .map((t) => t.icao);
  let clicked = null;
  for (let attempt = 0; attempt < 3 && !clicked; attempt++) {
    const target = await page.evaluate((icaos) => {
      const m = window.adsbMap;
      const drawn = m.drawn();
      const box = m.map.getContainer().getBoundingClientRect();
      const canvas = document.querySelector(".aircraft-canvas");
      const cbox = canvas.getBoundingClientRect();
      const ctx = canvas.getContext("2d");
      const scale = canvas.width / cbox.width;
      for (const icao of icaos) {
        const p = drawn[icao];
        if (!p || icao === m.selected()) continue;
        const [x, y] = p;
        if (x < 60 || y < 60 || x > box.width - 300 || y > box.height - 60) continue;
        // No other icon within two click radii, and no other aircraft's label (drawn from
        // 10 px right of its icon, 11 px above to 15 px below, up to ~90 px wide) over it.
        const clear = Object.entries(drawn).every(
          ([o, [ox, oy]]) => o === icao || (Math.hypot(ox - x, oy - y) > 24 && !(x - ox >= 4 && x - ox <= 100 && y - oy >= -17 && y - oy <= 21)),
        );
        if (!clear) continue;
        // The 3x3 device pixels around the centre: the fuselage there is under 3 px wide
        // between white strokes, and the sprite lands on whole pixels, so the one pixel at
        // the centre may be an anti-aliased edge (seen: 229,154,44 for CA's 224,134,0).
        const cx = Math.round((box.left + x - cbox.left) * scale);
        const cy = Math.round((box.top + y - cbox.top) * scale);
        const px = ctx.getImageData(cx - 1, cy - 1, 3, 3).data;
        const pixels = [];
        for (let i = 0; i < px.length; i += 4) pixels.push([px[i], px[i + 1], px[i + 2], px[i + 3]]);
        return { icao, x: box.left + x, y: box.top + y, pixels, mode: m.track(icao).mode };
      }
      return null;
    }, named);
    if (!target) break;
    const colours = { CV: [0x2f, 0x6f, 0xd6], CA: [0xe0, 0x86, 0x00], CT: [0xd6, 0x2f, 0x5b], CH: [0x1f, 0x9e, 0x55], CHCA: [0x8b, 0x4f, 0xd0] };
    const want = colours[target.mode];
    // The pixel of the nine nearest the mode's colour.
    const off = (px) => (want ? Math.max(...want.map((c, i) => Math.abs(c - px[i]))) : 0);
    target.pixel = target.pixels.reduce((a, b) => (off(b) < off(a) ? b : a));
    result.pixel = target.pixel;
    check(
      want && target.pixel[3] > 200 && want.every((c, i) => Math.abs(c - target.pixel[i]) <= 40),
      `the pixel under ${target.icao}'s icon is ${target.pixel}, not ${target.mode}'s colour ${want}`,
    );
    await page.mouse.click(target.x, target.y);
    await page.waitForSelector("#panel:not([hidden])", { timeout: 5000 });
    const sel = await page.evaluate(() => window.adsbMap.selected());
    if (sel === target.icao) clicked = target.icao;
  }
  check(clicked !== null, "no aircraft with a callsign could be clicked");
  if (clicked) {
    // The panel is redrawn at most every 250 ms: give it one turn.
    await sleep(300);
    const title = (await page.textContent("#panel-title"))?.trim();
    const one = await api(`api/v1/tracks/${clicked}`);
    result.clicked = clicked;
    result.panel_title = title;
    result.callsign = one.callsign;
    check(title === one.callsign, `panel of ${clicked} says ${JSON.stringify(title)}, the API ${JSON.stringify(one.callsign)}`);
    const fields = await page.$$eval("#panel-body table.fields tr", (rows) => rows.length);
    result.panel_fields = fields;
    result.api_fields = Object.keys(one).length;
    check(fields === Object.keys(one).length, `the panel lists ${fields} fields, the API ${Object.keys(one).length}`);
    const bars = await page.$$eval("#panel-body .prob", (rows) => rows.length);
    check(bars === 5, `${bars} mode probability bars`);
    const row = await page.$$eval("#list-rows tr.selected", (rows) => rows.map((r) => r.dataset.icao));
    check(row.length <= 1 && (row.length === 0 || row[0] === clicked), `list rows selected: ${row}`);
  }

  // A network outage: every connection cut, then 503 for every request until an aircraft
  // the page shows is retired (its `retire` event lost). The page
  // says so, reconnects by itself (the browser's retry meets the 503 and gives up; the
  // page's own backoff tries again), and drops the aircraft the new connection's state
  // does not have.
  const connections = await page.evaluate(() => window.adsbMap.connections());
  const beforeOutage = await shown();
  outage = true;
  for (const [c, u] of links) {
    c.destroy();
    u.destroy();
  }
  const noticed = await until(10000, () => page.evaluate(() => document.getElementById("c-stream").textContent !== "live"));
  check(noticed, "the page did not notice the outage in 10 s");
  result.outage_status = await page.textContent("#c-stream");
  // At least 3 s, and until an aircraft the page showed has been retired (at 10x, within
  // seconds).
  const outageStart = Date.now();
  const retiredDuring = await until(30000, async () => {
    const now = new Set((await api("api/v1/tracks")).tracks.map((t) => t.icao));
    return Date.now() - outageStart >= 3000 && beforeOutage.some((i) => !now.has(i));
  }, 500);
  check(retiredDuring, "no aircraft retired during 30 s of outage");
  result.outage_s = (Date.now() - outageStart) / 1000;
  outage = false;
  const back = await until(40000, () =>
    page.evaluate((n) => window.adsbMap.connections() > n && document.getElementById("c-stream").textContent === "live", connections),
  );
  check(back, "the page did not reconnect within 40 s of the outage's end");
  result.reconnected = back;
  const afterOutage = await agreeWithApi(20000);
  const lost = beforeOutage.filter((i) => !afterOutage.icaos.includes(i));
  result.after_outage = { markers: afterOutage.markers, tracks: afterOutage.tracks, same: afterOutage.same, retired_meanwhile: lost.length };
  check(afterOutage.same, `after the outage, the map and /api/v1/tracks differ: ${JSON.stringify({ ...afterOutage, icaos: undefined })}`);
  check(lost.length > 0, "no aircraft retired during the outage: the test proves nothing of the resync");

  // Retired aircraft leave the map: once some of those first shown are retired (a minute of
  // feed time without a message), the map still shows exactly the tracks listed.
  let gone = [];
  await until(60000, async () => {
    const now = new Set((await api("api/v1/tracks")).tracks.map((t) => t.icao));
    gone = firstIcaos.filter((i) => !now.has(i));
    return gone.length >= 3;
  }, 1000);
  result.retired = gone.length;
  check(gone.length >= 3, `only ${gone.length} of the first aircraft retired in 60 s`);
  const later = await agreeWithApi(20000);
  result.later = { markers: later.markers, tracks: later.tracks, same: later.same };
  check(later.same, `after retirements, the map and /api/v1/tracks differ: ${JSON.stringify({ ...later, icaos: undefined })}`);
  check(!gone.some((i) => later.icaos.includes(i)), "a retired aircraft is still on the map");
  result.events = await page.evaluate(() => window.adsbMap.events());
  check(result.events.retire > 0, "no retire event arrived");

  await sleep(Number(process.env.MAP_SCREENSHOT_WAIT_S ?? 0.5) * 1000);
  await page.screenshot({ path: screenshot });
  result.screenshot = screenshot;
  result.requests = requests;
  result.history = history;
  check(history.ok > 0 && history.points > 0, `no trail came from the history endpoint: ${JSON.stringify(history)}`);
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
  relay.close();
  for (const [c, u] of links) {
    c.destroy();
    u.destroy();
  }
}
console.log(JSON.stringify(result));
if (failures.length) {
  for (const f of failures) console.error(`FAIL: ${f}`);
  process.exit(1);
}
