// Browser acceptance of the web HMI (issue 11), in Debian's headless Chromium driven by
// playwright-core: the daemon runs the in-process plant through the throttle closure; the
// page's operating-point marker must move toward the control line during the closure (the
// recycle valve holds it there), the mode must read auto, and the deviation shown must match
// `antisurge status --json` within 1 % (percentage points of the control-line flow).
// Usage: node browser_test.mjs HMI_URL ANTISURGE_BIN STATUS_SOCKET SCREENSHOT
import { chromium } from "playwright-core";
import { execFileSync } from "node:child_process";

const [url, bin, socket, shot] = process.argv.slice(2);
const fail = (m) => { console.error("FAIL: " + m); process.exit(1); };
const browser = await chromium.launch({
  executablePath: "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync"],
});
const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
await page.goto(url);
await page.waitForFunction(() => window.hmiState && window.hmiState.mode === "auto", null, { timeout: 15000 });

// marker distance to the control line on the map, in map pixels (x), over the closure
const samples = [];
const t0 = Date.now();
while (Date.now() - t0 < 14000) {
  const s = await page.evaluate(() => {
    const m = document.getElementById("map").dataset;
    return { x: +m.markerX, c: +m.controlX, flow: +m.flow, mode: document.getElementById("mode").textContent,
             dev: document.getElementById("deviation").dataset.value };
  });
  samples.push({ t: (Date.now() - t0) / 1000, ...s });
  await page.waitForTimeout(250);
}
const first = samples.find((s) => Number.isFinite(s.x));
const last = samples[samples.length - 1];
const dist = (s) => Math.abs(s.x - s.c);
const maxDist = Math.max(...samples.map(dist).filter(Number.isFinite));
console.log(`marker: flow ${first.flow.toFixed(4)} -> ${last.flow.toFixed(4)}; ` +
  `distance to the control line ${dist(first).toFixed(1)} px at start, ${maxDist.toFixed(1)} px at most, ${dist(last).toFixed(1)} px at the end`);
if (!(last.flow < first.flow * 0.97)) fail(`the marker did not move left with the closure: ${first.flow} -> ${last.flow}`);
if (!(maxDist > 1 && dist(last) < 0.5 * maxDist)) fail(`the marker did not come back toward the control line: max ${maxDist}, end ${dist(last)}`);
if (last.mode !== "auto") fail(`mode reads ${last.mode}`);

// the deviation shown vs the daemon's own status, read back to back
const shown = parseFloat(await page.evaluate(() => document.getElementById("deviation").dataset.value));
const st = JSON.parse(execFileSync(bin, ["status", "--json", "--socket", socket]).toString());
console.log(`deviation: HMI ${shown.toFixed(3)} %, antisurge status ${st.deviation_pct.toFixed(3)} %`);
if (!(Math.abs(shown - st.deviation_pct) <= 1.0)) fail("deviation differs by more than 1 %");
await page.screenshot({ path: shot, fullPage: true });
console.log(`screenshot: ${shot}`);
await browser.close();
