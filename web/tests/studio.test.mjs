// Loomlight Studio in a real browser (Debian's chromium, headless, through playwright-core) against a real server
// and gateway: the controls are ListModels' schema for every model, a slider moves the lobe and the thumbnail, a
// refused value shows the server's message at its control, the next change cancels a render in flight on the
// server, no stack trace ever shows. Screenshots at 1280 x 800 go to $LOOMLIGHT_STUDIO_SCREENSHOTS (CTest:
// build/studio-screenshots) for a person to look at.
import assert from "node:assert/strict";
import { mkdirSync, readdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { after, before, describe, test } from "node:test";
import { spawnSync } from "node:child_process";
import {
  EDITOR_TOKEN, buildDir, callCount, connectCall, launchBrowser, pickMaterial, repo, startGateway, startServer,
  startTlsGateway, startTlsServer, startUnreadTable, viewsSettled, web,
} from "./harness.mjs";

const screenshots = process.env.LOOMLIGHT_STUDIO_SCREENSHOTS ?? join(repo, "build", "studio-screenshots");
const STACK = /\bat \S+ \(?\S+:\d+:\d+\)?|\.(ts|mjs|js):\d+:\d+/;

let server;
let gateway;
let browser;
let models;

before(async () => {
  mkdirSync(screenshots, { recursive: true });
  server = await startServer();
  gateway = await startGateway(server);
  browser = await launchBrowser();
  models = (await connectCall(gateway.url, "ListModels", {})).body.models;
});

after(async () => {
  await browser?.close();
  await gateway?.stop();
  await server?.stop();
});

async function openStudio(url = gateway.url) {
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  const problems = [];
  page.on("pageerror", (error) => problems.push(error.message));
  await page.goto(url);
  return { page, problems };
}

const settled = viewsSettled;

// RGBA pixels of a canvas, or of an image drawn into one.
async function pixels(page, selector) {
  return page.evaluate((selector) => {
    const element = document.querySelector(selector);
    const canvas = document.createElement("canvas");
    canvas.width = element.naturalWidth ?? element.width;
    canvas.height = element.naturalHeight ?? element.height;
    const context = canvas.getContext("2d");
    context.drawImage(element, 0, 0);
    return Array.from(context.getImageData(0, 0, canvas.width, canvas.height).data);
  }, selector);
}

function meanDifference(a, b) {
  assert.equal(a.length, b.length);
  let sum = 0;
  for (let i = 0; i < a.length; ++i) sum += Math.abs(a[i] - b[i]);
  return sum / a.length;
}

// Sets a control's value as a person does (input, then change events).
async function setControl(page, param, role, value) {
  await page.evaluate(({ param, role, value }) => {
    const input = document.querySelector(`.param[data-param="${param}"] [data-role="${role}"]`);
    input.value = value;
    input.dispatchEvent(new Event("input", { bubbles: true }));
    input.dispatchEvent(new Event("change", { bubbles: true }));
  }, { param, role, value });
}

const TYPES = { TYPE_REAL: "real", TYPE_INT: "int", TYPE_RGB: "rgb", TYPE_REAL_LIST: "list", TYPE_TEXT: "text" };

describe("Loomlight Studio", () => {
  test("the controls are ListModels' schema, for every model; the page's code names no parameter", async () => {
    const { page, problems } = await openStudio();
    await settled(page, ["#lobe"], false);
    const options = await page.$$eval("#model option", (list) => list.map((o) => o.value));
    assert.deepEqual(options, models.map((m) => m.name));
    for (const model of models) {
      await page.selectOption("#model", model.name);
      await page.waitForFunction((count) => document.querySelectorAll("#params .param").length === count &&
                                            true, model.params.length);
      const controls = await page.$$eval("#params .param", (list) => list.map((p) => {
        const value = p.querySelector('[data-role="value"]');
        return { name: p.dataset.param, type: p.dataset.type, tag: value?.tagName, inputType: value?.type,
                 min: value?.min, max: value?.max, title: p.title || p.querySelector("label")?.title || "" };
      }));
      assert.deepEqual(controls.map((c) => c.name), model.params.map((p) => p.name), model.name);
      model.params.forEach((schema, i) => {
        const control = controls[i];
        const type = TYPES[schema.type];
        assert.equal(control.type, type, `${model.name}.${schema.name}`);
        if (type === "real" || type === "int") {
          assert.equal(control.inputType, "range", `${model.name}.${schema.name}`);
          assert.equal(Number(control.min), schema.min ?? 0, `${model.name}.${schema.name} min`);
          assert.equal(Number(control.max), schema.max ?? 0, `${model.name}.${schema.name} max`);
        }
        if (type === "rgb") assert.equal(control.inputType, "color");
        assert.ok(control.title.includes(schema.description ?? ""), `${model.name}.${schema.name} description`);
      });
      const presets = await page.$$eval("#preset option", (list) => list.map((o) => o.value).filter((v) => v));
      for (const preset of model.presets) assert.ok(presets.includes(preset.name), `${model.name}: ${preset.name}`);
    }
    // No parameter's name is in the bundle: the controls come from the schema alone. (Short or common words,
    // such as `asset`, which the BTF picker sets, cannot be told apart from other code and are left out.)
    const bundle = readdirSync(join(web, "dist", "assets")).filter((f) => f.endsWith(".js"))
      .map((f) => readFileSync(join(web, "dist", "assets", f), "utf8")).join("\n");
    for (const model of models) {
      for (const param of model.params) {
        if (/[._]/.test(param.name) && param.name.length > 6) {
          assert.ok(!bundle.includes(`"${param.name}"`) && !bundle.includes(`'${param.name}'`),
                    `the page's code names ${param.name}`);
        }
      }
    }
    assert.deepEqual(problems, []);
    await page.close();
  });

  test("moving a slider changes the lobe and the thumbnail", async () => {
    const { page, problems } = await openStudio();
    await pickMaterial(page, "microcylinder", "velvet");
    await settled(page);
    await page.screenshot({ path: join(screenshots, "studio-velvet.png") });
    const lobe = await pixels(page, "#lobe");
    const thumbnail = await pixels(page, "#thumbnail");
    const change = await page.evaluate(() => window.studio.change);
    await setControl(page, "thread1.gamma_s", "value", "60");
    await page.waitForFunction((c) => window.studio.change > c, change);
    await settled(page);
    await page.screenshot({ path: join(screenshots, "studio-velvet-gamma-s-60.png") });
    assert.ok(meanDifference(lobe, await pixels(page, "#lobe")) > 0.5, "the lobe changed");
    assert.ok(meanDifference(thumbnail, await pixels(page, "#thumbnail")) > 0.5, "the thumbnail changed");
    const timings = await page.$$eval("#timings [data-rpc]", (rows) => rows.map((r) => r.dataset.rpc));
    for (const rpc of ["ListModels", "Evaluate", "Render"]) assert.ok(timings.includes(rpc), `timing of ${rpc}`);
    assert.ok((await page.textContent("#fidelity")).length > 0, "the fidelity report is shown");
    assert.deepEqual(problems, []);
    await page.close();
  });

  test("a refused value shows the server's message next to its control, and the views keep their image", async () => {
    const { page, problems } = await openStudio();
    await pickMaterial(page, "microcylinder", "velvet");
    await settled(page);
    const lobe = await pixels(page, "#lobe");
    const good = await page.$eval("#lobe", (e) => e.dataset.change);
    // The server's own words for this value, asked directly.
    const refused = await connectCall(gateway.url, "Evaluate",
      { material: { preset: "velvet", params: [{ name: "eta", values: [7] }] }, wi: [0, 0, 1], wo: [0, 0, 1] });
    const words = refused.body.message.replace(/^material\.params\[\d+\]\.values\[\d+\]: /, "");
    assert.match(words, /eta.*outside/);
    await setControl(page, "eta", "number", "7");
    const error = page.locator('.param[data-param="eta"] .param-error');
    await error.filter({ hasText: "outside" }).waitFor({ timeout: 60_000 });
    assert.ok((await error.textContent()).includes(words), await error.textContent());
    await page.screenshot({ path: join(screenshots, "studio-refused-value.png") });
    assert.equal(await page.$eval("#lobe", (e) => e.dataset.change), good, "the lobe still shows the last good material");
    assert.equal(meanDifference(lobe, await pixels(page, "#lobe")), 0);
    assert.doesNotMatch(await page.textContent("body"), STACK);
    assert.deepEqual(problems, []);
    await page.close();
  });

  test("the next change cancels the render in flight, as the server's metrics show", async () => {
    const { page } = await openStudio();
    await pickMaterial(page, "microcylinder", "velvet");
    await settled(page);
    const before = await callCount(server, "Render", "CANCELLED");
    // A change, then another while its thumbnail is still refining: the refinement's stream is aborted. (A render
    // may end just before the abort reaches the server; each try makes another.)
    for (let attempt = 0; attempt < 10 && (await callCount(server, "Render", "CANCELLED")) === before; ++attempt) {
      const change = await page.evaluate(() => window.studio.change);
      await setControl(page, "thread1.gamma_v", "value", String(20 + attempt));
      await page.waitForFunction((c) => {
        const t = document.querySelector("#thumbnail");
        return window.studio.change > c && t.dataset.change === String(window.studio.change) &&
               t.dataset.final !== "true";
      }, change, { timeout: 120_000, polling: 10 });
      await setControl(page, "thread1.gamma_v", "value", String(40 + attempt));
      await settled(page, ["#lobe"]);
      await new Promise((resolve) => setTimeout(resolve, 500)); // the server counts a cancelled call as it ends
    }
    assert.ok((await callCount(server, "Render", "CANCELLED")) > before, "a Render ended CANCELLED");
    await page.close();
  });

  test("a woven material shows its texture slice", async () => {
    const { page, problems } = await openStudio();
    await pickMaterial(page, "woven", "cotton_twill");
    await settled(page, ["#lobe", "#halfdiff", "#sphere", "#slice"]);
    assert.equal(await page.$eval("#slice", (e) => e.dataset.state), "done");
    assert.ok(await page.$eval("#slice", (e) => e.naturalWidth > 0));
    await page.screenshot({ path: join(screenshots, "studio-cotton-twill.png") });
    assert.deepEqual(problems, []);
    await page.close();
  });

  test("the current material downloads as an EXR table and a glTF fit", async () => {
    const { page, problems } = await openStudio();
    await pickMaterial(page, "microcylinder", "silk_shot");
    await settled(page, ["#lobe"], false);
    const download = async (button) => {
      const [file] = await Promise.all([page.waitForEvent("download", { timeout: 240_000 }), page.click(button)]);
      return { name: file.suggestedFilename(), bytes: readFileSync(await file.path()) };
    };
    const exr = await download("#download-exr");
    assert.match(exr.name, /\.exr$/);
    assert.deepEqual([...exr.bytes.subarray(0, 4)], [0x76, 0x2f, 0x31, 0x01]); // OpenEXR's magic number
    const glb = await download("#download-gltf");
    assert.match(glb.name, /\.glb$/);
    assert.equal(glb.bytes.subarray(0, 4).toString("latin1"), "glTF");
    const json = JSON.parse(glb.bytes.subarray(20, 20 + glb.bytes.readUInt32LE(12)).toString("utf8"));
    assert.ok(json.materials[0].extensions.KHR_materials_sheen, "the fit's sheen is in the file");
    assert.deepEqual(problems, []);
    await page.close();
  });

  test("a stored BTF asset is listed and previewed", async () => {
    const made = spawnSync(join(buildDir, "loomlight"), ["--server", server.target, "--timeout", "300", "btf",
      "create", "twill_small", "--preset", "cotton_twill", "--grid", "h2", "--resolution", "16", "--components", "4"],
    { encoding: "utf8" });
    assert.equal(made.status, 0, made.stderr);
    const { page, problems } = await openStudio();
    await settled(page, ["#lobe"], false);
    await page.click("#btfs-refresh");
    await page.click('[data-asset="twill_small"]');
    await page.waitForFunction(() => document.querySelector("#model").value === "btf");
    await settled(page, ["#lobe", "#halfdiff", "#sphere", "#slice"], false);
    assert.equal(await page.$eval("#lobe", (e) => e.dataset.state), "done");
    await page.screenshot({ path: join(screenshots, "studio-btf-asset.png") });
    assert.deepEqual(problems, []);
    await page.close();
  });

  test("with the server gone, the page says so in one line, without a stack trace", async () => {
    const dead = await startGateway({ target: "127.0.0.1:1" });
    try {
      const { page } = await openStudio(dead.url);
      await page.waitForFunction(() => (document.querySelector("#status")?.textContent ?? "").length > 0,
                                 null, { timeout: 60_000 });
      const status = await page.textContent("#status");
      assert.ok(status.length <= 400, status);
      assert.match(status, /unreachable/i);
      assert.doesNotMatch(await page.textContent("body"), STACK);
      await page.screenshot({ path: join(screenshots, "studio-server-unreachable.png") });
      await page.close();
    } finally {
      await dead.stop();
    }
  });
});

describe("Loomlight Studio on a server that requires tokens", () => {
  let tlsServer;
  let tlsGateway;
  before(async () => {
    tlsServer = await startTlsServer();
    tlsGateway = await startTlsGateway(tlsServer);
  });
  after(async () => {
    await tlsGateway?.stop();
    await tlsServer?.stop();
  });

  test("without a token the page says the server wants one; with the token it works", async () => {
    const { page } = await openStudio(tlsGateway.url);
    await page.waitForFunction(() => /wants a token/.test(document.querySelector("#status").textContent),
                               null, { timeout: 60_000 });
    assert.match(await page.textContent("#status"), /bearer/i, "with the server's own words");
    assert.doesNotMatch(await page.textContent("body"), STACK);
    await page.fill("#token", EDITOR_TOKEN);
    await Promise.all([page.waitForNavigation(), page.click('#token-form button[type="submit"]')]);
    await settled(page, ["#lobe", "#halfdiff", "#sphere"], false);
    assert.equal(await page.$eval("#lobe", (e) => e.dataset.state), "done");
    assert.equal(await page.inputValue("#token"), EDITOR_TOKEN, "kept for the tab");
    await page.close();
  });
});

describe("Loomlight Studio on a busy server", () => {
  let busyServer;
  let busyGateway;
  before(async () => {
    // One long call (TextureSlice, Render, Tabulate) per client, and every browser reaches the server as the
    // gateway's one client.
    busyServer = await startServer(["--max-long-calls-per-client", "1"]);
    busyGateway = await startGateway(busyServer);
  });
  after(async () => {
    await busyGateway?.stop();
    await busyServer?.stop();
  });

  test("a view the server turns away as busy tries again until it is served", async () => {
    // Another browser's unread table holds the one slot: the page's slice and thumbnail are turned away until it
    // goes, and then served without a reload or a new change.
    const table = startUnreadTable(busyGateway.url);
    const turnedAway = async () => (await callCount(busyServer, "TextureSlice", "RESOURCE_EXHAUSTED")) +
                                   (await callCount(busyServer, "Render", "RESOURCE_EXHAUSTED"));
    const { page, problems } = await openStudio(busyGateway.url);
    try {
      await pickMaterial(page, "woven", "cotton_twill");
      await settled(page, ["#lobe", "#halfdiff", "#sphere"], false);
      const change = await page.evaluate(() => window.studio.change);
      for (const deadline = Date.now() + 120_000; (await turnedAway()) < 2;) {
        assert.ok(Date.now() < deadline, "the server never turned the page's long calls away");
        await new Promise((resolve) => setTimeout(resolve, 200));
      }
      assert.equal(await page.$eval("#thumbnail", (e) => e.dataset.state), "busy", "busy, not failed");
      table.destroy();
      await settled(page, ["#lobe", "#halfdiff", "#sphere", "#slice"]);
      assert.equal(await page.evaluate(() => window.studio.change), change, "served for the same change");
      assert.equal(await page.textContent("#status"), "");
      assert.deepEqual(problems, []);
    } finally {
      table.destroy();
      await page.close();
    }
  });
});
