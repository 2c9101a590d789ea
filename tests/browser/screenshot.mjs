// The README's picture (docs/map.png) of a running daemon's map:
//
//   node tests/browser/screenshot.mjs http://127.0.0.1:PORT/ OUT.png [WAIT_S] [ZOOM]
//
// Opens the page (1440x900), lets it run WAIT_S seconds (default 5: trails grow), selects a
// manoeuvring aircraft (a coordinated turn if there is one) through the list's search, as a
// user would, zooms to ZOOM (default: the page's own fit) and saves the screenshot.
import { chromium } from "playwright-core";

const [url, out, waitArg, zoomArg] = process.argv.slice(2);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  headless: true,
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1440, height: 900 } });
  await page.goto(url);
  await page.waitForFunction(() => window.adsbMap?.settled() && window.adsbMap.icaos().length > 0, null, { timeout: 60000 });
  await page.waitForTimeout(Number(waitArg ?? 5) * 1000);
  const pick = await page.evaluate(() => {
    const m = window.adsbMap;
    const rank = { CT: 0, CA: 1, CHCA: 2, CH: 3 };
    const inView = m.map.getBounds().pad(-0.2);
    const ts = m.icaos().map((i) => m.track(i)).filter((t) => t.callsign && !t.on_ground && t.mode in rank && inView.contains([t.lat, t.lon]));
    ts.sort((a, b) => rank[a.mode] - rank[b.mode]);
    return ts[0]?.callsign ?? null;
  });
  if (pick) {
    await page.fill("#f-search", pick.toLowerCase());
    await page.waitForTimeout(300);
    await page.click(`#list-rows tr[data-icao]`);
    await page.fill("#f-search", "");
    if (zoomArg) await page.evaluate((z) => void window.adsbMap.map.setZoom(z), Number(zoomArg));
    await page.waitForTimeout(2500);
  }
  await page.screenshot({ path: out });
  console.log(JSON.stringify({ selected: pick, out }));
} finally {
  await browser.close();
}
