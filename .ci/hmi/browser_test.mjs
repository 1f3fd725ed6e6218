// Browser acceptance of the web HMI (issue 11), in Debian's headless Chromium driven by
// playwright-core: the daemon runs the in-process plant through the throttle closure; the
// page's operating-point marker must move toward the control line during the closure (the
// recycle valve holds it there), the mode must read auto, and the deviation shown must match
// `antisurge status --json` within 1 % (relative). The page shows the control cycle of the
// snapshot it displays; the daemon reports that same snapshot (`status --json --cycle N`), so
// values of one instant are compared, at every sample through the closure. The page rounds
// to 0.01 %: near the control line (deviation ~0) the allowance is that rounding, 0.005 %.
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
const compared = [];
const t0 = Date.now();
while (Date.now() - t0 < 14000) {
  // one evaluate: what the page shows now, all from one snapshot (one tick of the page)
  const s = await page.evaluate(() => {
    const m = document.getElementById("map").dataset, d = document.getElementById("deviation");
    return { x: +m.markerX, c: +m.controlX, flow: +m.flow, mode: document.getElementById("mode").textContent,
             devText: d.textContent, dev: d.dataset.value, cycle: document.getElementById("cycle").dataset.value };
  });
  samples.push({ t: (Date.now() - t0) / 1000, ...s });
  if (s.cycle && s.dev !== "") {
    const st = JSON.parse(execFileSync(bin, ["status", "--json", "--socket", socket, "--cycle", s.cycle]).toString());
    const latest = JSON.parse(execFileSync(bin, ["status", "--json", "--socket", socket]).toString());
    compared.push({ t: samples[samples.length - 1].t, cycle: +s.cycle, devText: s.devText, shown: parseFloat(s.devText), value: +s.dev,
                    status: st.deviation_pct, statusCycle: st.cycle, latest: latest.deviation_pct, latestCycle: latest.cycle });
  }
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

// the deviation shown vs the daemon's own report of the same snapshot
if (compared.length < 20) fail(`only ${compared.length} samples compared with antisurge status`);
let worst = null, worstRel = 0, worstLatest = 0;
for (const c of compared) {
  if (c.statusCycle !== c.cycle) fail(`status --cycle ${c.cycle} reported cycle ${c.statusCycle}`);
  const allow = Math.max(0.01 * Math.abs(c.status), 0.005);
  const err = Math.abs(c.shown - c.status);
  if (!(err <= allow)) fail(`cycle ${c.cycle}: the HMI shows ${c.shown} %, antisurge status ${c.status} % (allowed ${allow})`);
  if (!(Math.abs(c.value - c.status) <= 0.01 * Math.abs(c.status))) fail(`cycle ${c.cycle}: page value ${c.value} vs status ${c.status}`);
  const rel = err / Math.max(Math.abs(c.status), 1e-12);
  if (!worst || err / allow > Math.abs(worst.shown - worst.status) / Math.max(0.01 * Math.abs(worst.status), 0.005)) worst = c;
  if (Math.abs(c.status) >= 0.5) worstRel = Math.max(worstRel, rel);
  worstLatest = Math.max(worstLatest, Math.abs(c.latest - c.value) / Math.max(Math.abs(c.latest), 1e-12));
}
const devs = compared.map((c) => c.status);
console.log(`deviation: ${compared.length} samples from ${Math.min(...devs).toFixed(3)} % to ${Math.max(...devs).toFixed(3)} %, ` +
  `HMI text vs antisurge status --json --cycle N: worst relative ${(100 * worstRel).toFixed(3)} % where |deviation| >= 0.5 %, ` +
  `worst case cycle ${worst.cycle}: HMI shows "${worst.devText}" vs status ${worst.status.toFixed(4)} %`);
console.log(`(for comparison, the page's value vs the latest status read right after: worst relative ${(100 * worstLatest).toFixed(2)} %, ` +
  `cycles apart up to ${Math.max(...compared.map((c) => c.latestCycle - c.cycle))})`);
await page.screenshot({ path: shot, fullPage: true });
console.log(`screenshot: ${shot}`);
await browser.close();
