// How the map page keeps up with a big fleet (README's figures; not part of the test suite):
//
//   node tests/browser/perf.mjs http://127.0.0.1:PORT/ [MIN_AIRCRAFT] [SECONDS]
//
// Waits for MIN_AIRCRAFT markers (default 900), then for SECONDS (default 20) measures in
// the page: frames drawn, the gaps between them (p50, p99, max), long tasks (> 50 ms, the
// main thread busy), events received, and the JS heap. Prints one JSON line.
// PERF_SETUP=script runs in the page first (e.g. to turn layers off and compare).
import { chromium } from "playwright-core";

const [url, minArg, secArg] = process.argv.slice(2);
const minAircraft = Number(minArg ?? 900);
const seconds = Number(secArg ?? 20);
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  headless: true,
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--enable-precise-memory-info"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1440, height: 900 } });
  await page.goto(url);
  const t0 = Date.now();
  await page.waitForFunction((n) => window.adsbMap && window.adsbMap.icaos().length >= n, minAircraft, { timeout: 120000, polling: 500 });
  const loadS = (Date.now() - t0) / 1000;
  await page.waitForFunction(() => window.adsbMap.settled(), null, { timeout: 30000 });
  // PERF_SETUP: script run in the page before measuring (e.g. turning layers off).
  if (process.env.PERF_SETUP) await page.evaluate(process.env.PERF_SETUP);
  const r = await page.evaluate(async (ms) => {
    const gaps = [];
    let long = 0;
    let longMs = 0;
    const obs = new PerformanceObserver((l) => {
      for (const e of l.getEntries()) {
        long++;
        longMs += e.duration;
      }
    });
    obs.observe({ type: "longtask", buffered: false });
    const e0 = window.adsbMap.events();
    let last = performance.now();
    const end = last + ms;
    await new Promise((done) => {
      const tick = (now) => {
        gaps.push(now - last);
        last = now;
        if (now < end) requestAnimationFrame(tick);
        else done();
      };
      requestAnimationFrame(tick);
    });
    obs.disconnect();
    const e1 = window.adsbMap.events();
    gaps.sort((a, b) => a - b);
    const q = (p) => gaps[Math.min(gaps.length - 1, Math.floor(p * gaps.length))];
    return {
      markers: window.adsbMap.icaos().length,
      drawn: Object.keys(window.adsbMap.drawn()).length,
      backlog: window.adsbMap.backlog(),
      frames_per_s: gaps.length / (ms / 1000),
      frame_gap_ms: { p50: q(0.5), p99: q(0.99), max: gaps[gaps.length - 1] },
      long_tasks: long,
      long_task_ms_per_s: longMs / (ms / 1000),
      track_events_per_s: (e1.track - e0.track) / (ms / 1000),
      js_heap_mb: performance.memory ? performance.memory.usedJSHeapSize / 1048576 : null,
    };
  }, seconds * 1000);
  r.load_s = loadS;
  console.log(JSON.stringify(r));
} finally {
  await browser.close();
}
