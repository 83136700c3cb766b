// Loomlight Studio's latency as a designer feels it: from a slider's change to the updated lobe, to the first
// thumbnail and to the final one, over 100 changes in Debian's chromium (headless, playwright-core) through the
// gateway to a server on this machine. The baseline, measured in the same run: an empty call (grpc.health.v1
// Check) from the page through the gateway. Next to the thumbnail's times, its error: how far the first
// (quick) image is from the final one. Starts with the CPU calibration loop of every report
// (build/bench/loomlight_bench --calibration). Writes bench/report-studio.md.
//   node web/bench/studio-latency.mjs [--changes N]    (after scripts/build-web.sh and a build)
import { spawnSync } from "node:child_process";
import { writeFileSync } from "node:fs";
import { cpus, loadavg } from "node:os";
import { join } from "node:path";
import { parseArgs } from "node:util";
import {
  buildDir, connectCall, launchBrowser, pickMaterial, repo, startGateway, startServer,
} from "../tests/harness.mjs";

const { values } = parseArgs({ options: { changes: { type: "string", default: "100" } } });
const changes = Number(values.changes);
const PARAM = "thread1.gamma_s"; // velvet's surface highlight width: moves the lobe and the thumbnail alike

function quantile(sorted, q) {
  const i = (sorted.length - 1) * q;
  const lo = Math.floor(i);
  return sorted[lo] + (sorted[Math.min(lo + 1, sorted.length - 1)] - sorted[lo]) * (i - lo);
}
const summary = (list) => {
  const sorted = [...list].sort((a, b) => a - b);
  return { median: quantile(sorted, 0.5), p95: quantile(sorted, 0.95), n: sorted.length };
};
const ms = (x) => (x >= 100 ? x.toFixed(0) : x.toFixed(1));

const calibration = spawnSync(join(buildDir, "bench", "loomlight_bench"), ["--calibration"], { encoding: "utf8" });
const calibrationLine = calibration.status === 0
  ? `a fixed single-thread loop (2^26 dependent xorshift and multiply-add steps) took ${calibration.stdout.trim()} ms, ` +
    "best of 3 (divide a time by it to compare reports of different days)"
  : "skipped: build/bench/loomlight_bench is not built (cmake -DLOOMLIGHT_BENCH=ON)";

const server = await startServer();
const gateway = await startGateway(server);
const browser = await launchBrowser();
const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
await page.goto(gateway.url);
await pickMaterial(page, "microcylinder", "velvet");

// Page-side instruments: the time each view's data-change / data-final reached a change, seen by a
// MutationObserver as the page sets them.
await page.evaluate(() => {
  window.bench = { marks: {} };
  const mark = (change, what) => {
    const key = `${change}`;
    window.bench.marks[key] ??= {};
    window.bench.marks[key][what] ??= performance.now();
  };
  const observe = (selector, callback) => new MutationObserver(() => callback(document.querySelector(selector)))
    .observe(document.querySelector(selector), { attributes: true });
  observe("#lobe", (e) => { if (e.dataset.state === "done") mark(e.dataset.change, "lobe"); });
  // The thumbnail's first and final images of a change, kept as pixels: the first image's error is its RMS
  // difference from the final one.
  const capture = (image) => {
    const canvas = document.createElement("canvas");
    canvas.width = image.naturalWidth;
    canvas.height = image.naturalHeight;
    const context = canvas.getContext("2d");
    context.drawImage(image, 0, 0);
    return context.getImageData(0, 0, canvas.width, canvas.height).data;
  };
  window.bench.firstPixels = {};
  window.bench.firstError = {};
  observe("#thumbnail", (e) => {
    const change = e.dataset.change;
    if (!change) return;
    const final = e.dataset.final === "true";
    const fresh = !(window.bench.marks[change] ?? {}).first;
    mark(change, "first");
    if (final) mark(change, "final");
    e.decode().then(() => {
      if (fresh && !final) window.bench.firstPixels[change] = capture(e);
      if (final && window.bench.firstPixels[change]) {
        const a = window.bench.firstPixels[change];
        const b = capture(e);
        let sum = 0;
        let count = 0;
        for (let i = 0; i < a.length && a.length === b.length; ++i) {
          if (i % 4 !== 3) { sum += (a[i] - b[i]) ** 2; ++count; }
        }
        window.bench.firstError[change] = count ? Math.sqrt(sum / count) : null;
      }
    }).catch(() => {});
  });
});

async function waitFinal(change) {
  await page.waitForFunction((c) => {
    const t = document.querySelector("#thumbnail");
    const l = document.querySelector("#lobe");
    return t.dataset.change === String(c) && t.dataset.final === "true" && l.dataset.change === String(c) &&
           l.dataset.state === "done";
  }, change, { timeout: 300_000, polling: 5 });
}
await waitFinal(await page.evaluate(() => window.studio.change));

// The baseline: an empty call from the page through the gateway, 100 times.
const empty = await page.evaluate(async () => {
  const times = [];
  for (let i = 0; i < 100; ++i) {
    const start = performance.now();
    const response = await fetch("grpc.health.v1.Health/Check", {
      method: "POST", headers: { "content-type": "application/json" }, body: "{}" });
    await response.json();
    times.push(performance.now() - start);
  }
  return times;
});

const lobe = [];
const first = [];
const final = [];
const firstError = [];
for (let i = 0; i < changes; ++i) {
  const value = String(8 + (i % 10) * 4); // 8..44 degrees, never the same twice in a row
  const { change, start } = await page.evaluate(({ param, value }) => {
    const input = document.querySelector(`.param[data-param="${param}"] [data-role="value"]`);
    const before = window.studio.change;
    const start = performance.now();
    input.value = value;
    input.dispatchEvent(new Event("input", { bubbles: true }));
    input.dispatchEvent(new Event("change", { bubbles: true }));
    return { change: Math.max(window.studio.change, before + 1), start };
  }, { param: PARAM, value });
  // The first image's pixels are kept by the page when it shows them (below); wait for the final one.
  await waitFinal(change);
  const marks = await page.evaluate((c) => window.bench.marks[String(c)], change);
  lobe.push(marks.lobe - start);
  first.push(marks.first - start);
  final.push(marks.final - start);
  await page.waitForFunction((c) => String(c) in window.bench.firstError || !(String(c) in window.bench.firstPixels),
                             change, { timeout: 10_000 }).catch(() => {});
  const error = await page.evaluate((c) => window.bench.firstError[String(c)] ?? null, change);
  if (error !== null) firstError.push(error);
}

// The lobe's error: the float kernels against the double reference, on an in-plane fan of the lobe's directions.
const fan = { wi: [], wo: [] };
for (const incidence of [30, 60]) {
  for (let k = 0; k < 181; ++k) {
    const t = ((k - 90) * Math.PI) / 180;
    const i = (incidence * Math.PI) / 180;
    fan.wi.push(-Math.sin(i), 0, Math.cos(i));
    fan.wo.push(Math.sin(t) * Math.cos(0), 0, Math.cos(t));
  }
}
const evaluate = async (precision) => (await connectCall(gateway.url, "Evaluate",
  { material: { preset: "velvet" }, wi: fan.wi, wo: fan.wo, precision })).body.f;
const [f32, f64] = [await evaluate("PRECISION_FP32"), await evaluate("PRECISION_FP64")];
const peak = Math.max(...f64.map(Math.abs));
const lobeError = Math.max(...f32.map((v, i) => Math.abs(v - f64[i]))) / peak;

await browser.close();
await gateway.stop();
await server.stop();

const revision = spawnSync("git", ["-C", repo, "rev-parse", "--short", "HEAD"], { encoding: "utf8" }).stdout.trim();
const dirty = spawnSync("git", ["-C", repo, "status", "--porcelain", "--untracked-files=no"], { encoding: "utf8" })
  .stdout.trim() ? " (with local changes)" : "";
const row = (name, list, note) => {
  const s = summary(list);
  return `| ${name} | ${ms(s.median)} | ${ms(s.p95)} | ${s.n} | ${note} |`;
};
const errorNote = firstError.length
  ? `first image vs final: RMS ${summary(firstError).median.toFixed(1)} of 255 (median over changes)`
  : "the page reports no first-image error";
const report = `# Loomlight Studio latency

\`node web/bench/studio-latency.mjs\` at ${revision}${dirty}, ${new Date().toISOString().slice(0, 16).replace("T", " ")} UTC.

- CPU calibration: ${calibrationLine}
- CPU: ${cpus()[0]?.model ?? "?"}, ${cpus().length} hardware threads; load average ${loadavg().map((x) => x.toFixed(2)).join(" ")} at the end
- Server, gateway and chromium (headless) all on this machine, on loopback: the browser's rendering and the
  server's kernels share its cores.

${changes} changes of one slider (\`${PARAM}\` of the preset velvet, 8 to 44 degrees), each waited for in full
before the next; times in ms from the slider's change event to the view showing that change:

| from a slider change to | median (ms) | p95 (ms) | changes | error / note |
|---|---|---|---|---|
${row("the updated lobe (Evaluate)", lobe, `float kernels: ${lobeError.toExponential(1)} of the lobe's peak from the double reference (max over 362 lobe directions)`)}
${row("the first thumbnail", first, errorNote)}
${row("the final thumbnail", final, "the page's last refinement")}
${row("baseline: an empty call (health Check) through the gateway", empty, "browser to gateway to server and back")}
`;
writeFileSync(join(repo, "bench", "report-studio.md"), report);
console.log(report);
