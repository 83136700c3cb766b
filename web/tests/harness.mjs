// Real processes for the page's tests: a Loomlight server (build/loomlight-server, port 0, its own data directory,
// metrics on), the gateway (web/gateway/main.mjs, port 0) in front of it, and Debian's chromium driven by
// playwright-core. $LOOMLIGHT_BUILD_DIR names the build tree (default ./build), $CHROMIUM the browser.
import { spawn, spawnSync } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { connect as netConnect } from "node:net";
import { tmpdir } from "node:os";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

export const web = join(dirname(fileURLToPath(import.meta.url)), "..");
export const repo = join(web, "..");
export const buildDir = process.env.LOOMLIGHT_BUILD_DIR ?? join(repo, "build");
export const tlsDir = join(repo, "tests", "data", "tls");
export const EDITOR_TOKEN = "editor-token-0123456789abcdef";     // tests/data/tls/tokens.txt: every call
export const PIPELINE_TOKEN = "pipeline-token-0123456789abcdef"; // Render, ListModels and metrics only

// Waits until `pattern` appears in what `read()` returns, or the process exits, or 300 s pass.
async function waitFor(read, pattern, child, what) {
  const deadline = Date.now() + 300_000;
  for (;;) {
    const found = pattern.exec(read());
    if (found) return found;
    if (child.exitCode !== null || Date.now() > deadline) {
      throw new Error(`${what} did not start:\n${read().slice(-3000)}`);
    }
    await new Promise((resolve) => setTimeout(resolve, 100));
  }
}

function collect(child) {
  let text = "";
  child.stdout.on("data", (chunk) => { text += chunk; });
  child.stderr.on("data", (chunk) => { text += chunk; });
  return () => text;
}

function stopper(child, dir) {
  return async () => {
    if (child.exitCode === null) {
      const exited = new Promise((resolve) => child.once("exit", resolve));
      child.kill("SIGTERM");
      const timer = setTimeout(() => child.kill("SIGKILL"), 20_000);
      await exited;
      clearTimeout(timer);
    }
    if (dir) rmSync(dir, { recursive: true, force: true });
  };
}

/** A Loomlight server on a free loopback port: { target, port, metricsPort, log(), stop() }. */
export async function startServer(extraArgs = []) {
  const dir = mkdtempSync(join(tmpdir(), "loomlight-web-"));
  const child = spawn(join(buildDir, "loomlight-server"),
    ["--address", "127.0.0.1:0", "--metrics-address", "127.0.0.1:0", "--data-dir", join(dir, "data"), ...extraArgs],
    { env: { ...process.env, POCL_CACHE_DIR: process.env.POCL_CACHE_DIR ?? join(buildDir, "pocl-cache") } });
  const log = collect(child);
  const port = Number((await waitFor(log, /serving on port (\d+)/, child, "loomlight-server"))[1]);
  const metricsPort = Number((await waitFor(log, /metrics on port (\d+)/, child, "loomlight-server"))[1]);
  return { target: `127.0.0.1:${port}`, port, metricsPort, log, stop: stopper(child, dir) };
}

/** The TLS server of the access tests: the test certificate, the test tokens. */
export function startTlsServer() {
  return startServer(["--tls-cert", join(tlsDir, "server.pem"), "--tls-key", join(tlsDir, "server.key"),
                      "--tokens", join(tlsDir, "tokens.txt")]);
}

/** The gateway in front of `server`: { url, stop() }. */
export async function startGateway(server, extraArgs = []) {
  const child = spawn(process.execPath,
    [join(web, "gateway", "main.mjs"), "--listen", "127.0.0.1:0", "--upstream", server.target, ...extraArgs]);
  const log = collect(child);
  const url = (await waitFor(log, /the page is at (http:\/\/\S+\/)/, child, "the gateway"))[1];
  return { url, log, stop: stopper(child) };
}

/** The gateway in front of startTlsServer's server: trusting the test CA, whose certificate names "localhost". */
export function startTlsGateway(server) {
  return startGateway(server, ["--upstream-tls-ca", join(tlsDir, "ca.pem"), "--upstream-server-name", "localhost"]);
}

/** Picks a model, then one of its presets, as a designer does (a model resets the preset list). */
export async function pickMaterial(page, model, preset) {
  await page.selectOption("#model", model);
  await page.selectOption("#preset", preset);
}

/** The cells of UNREAD_TABLE: 32 x 64 x 32 x 64, 50 MB of RAW floats. */
export const UNREAD_TABLE_CELLS = 32 * 64 * 32 * 64;

/**
 * A browser that asks the gateway for a 50 MB table (Tabulate, the Connect protocol over a raw socket) and never
 * reads it: the call stays open on the server, holding one of its client's long-call slots, until the returned
 * socket is destroyed.
 */
export function startUnreadTable(url) {
  const { port, hostname } = new URL(url);
  const socket = netConnect(Number(port), hostname);
  const message = Buffer.from(JSON.stringify({
    material: { preset: "velvet" }, format: "TABLE_FORMAT_RAW",
    anisotropic: { thetaICount: 32, phiICount: 64, thetaOCount: 32, phiOCount: 64 },
  }));
  const envelope = Buffer.alloc(5); // Connect's envelope: flags 0, then the message's length
  envelope.writeUInt32BE(message.length, 1);
  socket.write("POST /loomlight.v1.Loomlight/Tabulate HTTP/1.1\r\nHost: x\r\n" +
               "content-type: application/connect+json\r\nconnect-protocol-version: 1\r\n" +
               `content-length: ${message.length + 5}\r\n\r\n`);
  socket.write(Buffer.concat([envelope, message]));
  socket.pause();
  return socket;
}

/** Headless Debian chromium through playwright-core. */
export async function launchBrowser() {
  const { chromium } = await import("playwright-core");
  return chromium.launch({ executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium", headless: true,
                           args: ["--no-sandbox", "--disable-gpu"] });
}

/** A Connect (JSON) unary call through the gateway, as a browser makes it: { status, body }. */
export async function connectCall(url, method, request, headers = {}) {
  const response = await fetch(new URL(`loomlight.v1.Loomlight/${method}`, url), {
    method: "POST",
    headers: { "content-type": "application/json", ...headers },
    body: JSON.stringify(request),
  });
  return { status: response.status, body: await response.json() };
}

/** The server's Prometheus counter loomlight_calls_total{rpc, code}. */
export async function callCount(server, rpc, code) {
  const text = await (await fetch(`http://127.0.0.1:${server.metricsPort}/metrics`)).text();
  const line = text.split("\n").find((l) => l.startsWith("loomlight_calls_total{") &&
                                         l.includes(`rpc="${rpc}"`) && l.includes(`code="${code}"`));
  return line ? Number(line.split(" ").pop()) : 0;
}

/** The model names `build/loomlight models` prints: an independent client's view of ListModels. */
export function cliModels(server) {
  const result = spawnSync(join(buildDir, "loomlight"), ["--server", server.target, "models"], { encoding: "utf8" });
  if (result.status !== 0) throw new Error(result.stderr);
  return [...result.stdout.matchAll(/^model (\S+):/gm)].map((m) => m[1]);
}

export const readText = (path) => readFileSync(path, "utf8");

/**
 * Waits until every view named reflects the page's current change (data-change) and is done drawing, and with
 * `final` the thumbnail's last refinement too (docs: the page's contract in web/src/main.ts).
 */
export async function viewsSettled(page, selectors = ["#lobe", "#halfdiff", "#sphere"], final = true) {
  try {
    await viewsReady(page, selectors, final);
  } catch (error) {
    // What the page showed when it did not settle: each view's state and change, the status line, the last calls.
    const seen = await page.evaluate(() => ({
      change: window.studio?.change,
      views: [...document.querySelectorAll("[data-state]")].map((e) =>
        `#${e.id} ${e.dataset.state} change ${e.dataset.change ?? "-"}${e.dataset.final ? " final" : ""}`),
      status: document.querySelector("#status")?.textContent,
      errors: [...document.querySelectorAll(".param-error")].map((e) => e.textContent).filter(Boolean),
      calls: [...document.querySelectorAll("#timings tr[data-rpc]")].slice(0, 12).map((r) => r.textContent),
    })).catch(() => ({}));
    error.message += `\nthe page: ${JSON.stringify(seen, null, 1)}`;
    throw error;
  }
}

async function viewsReady(page, selectors, final) {
  await page.waitForFunction(({ selectors, final }) => {
    const change = String(window.studio?.change ?? "");
    const ready = selectors.every((s) => {
      const element = document.querySelector(s);
      return element && element.dataset.change === change &&
             (element.dataset.state === "done" || element.dataset.state === "hidden");
    });
    const thumbnail = document.querySelector("#thumbnail");
    return change !== "" && ready &&
           (!final || (thumbnail.dataset.change === change && thumbnail.dataset.final === "true"));
  }, { selectors, final }, { timeout: 240_000, polling: 100 });
}
