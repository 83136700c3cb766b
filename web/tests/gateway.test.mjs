// The gateway against a real server: every call forwarded as it is (errors with the server's code and message,
// streams, cancellation), tokens and TLS passed through with no policy added, request sizes bounded like the
// server's, a slow or stalled browser never holding up another, and only the built page's files served.
import assert from "node:assert/strict";
import { connect as netConnect } from "node:net";
import { after, before, describe, test } from "node:test";
import { createClient } from "@connectrpc/connect";
import { createConnectTransport } from "@connectrpc/connect-node";
import { Loomlight } from "../gen/loomlight/v1/loomlight_pb.js";
import {
  EDITOR_TOKEN, PIPELINE_TOKEN, UNREAD_TABLE_CELLS, callCount, cliModels, connectCall, startGateway, startServer,
  startTlsGateway, startTlsServer, startUnreadTable,
} from "./harness.mjs";

const UP = [0, 0, 1];

function nodeClient(url, headers = {}) {
  const transport = createConnectTransport({
    baseUrl: url, httpVersion: "1.1", useBinaryFormat: true,
    interceptors: [(next) => (request) => {
      for (const [name, value] of Object.entries(headers)) request.header.set(name, value);
      return next(request);
    }],
  });
  return createClient(Loomlight, transport);
}

async function eventually(check, what) {
  const deadline = Date.now() + 60_000;
  while (!(await check())) {
    if (Date.now() > deadline) assert.fail(`${what}: not within 60 s`);
    await new Promise((resolve) => setTimeout(resolve, 100));
  }
}

describe("gateway in front of a plaintext server", () => {
  let server;
  let gateway;
  before(async () => {
    server = await startServer();
    gateway = await startGateway(server);
  });
  after(async () => {
    await gateway?.stop();
    await server?.stop();
  });

  test("ListModels through the gateway lists what the C++ client lists", async () => {
    const { status, body } = await connectCall(gateway.url, "ListModels", {});
    assert.equal(status, 200);
    assert.deepEqual(body.models.map((m) => m.name), cliModels(server));
  });

  test("a refused request comes back with the server's code and message, and no stack", async () => {
    const { status, body } = await connectCall(gateway.url, "Evaluate",
      { material: { preset: "velvet" }, wi: [0, 0, 2], wo: UP });
    assert.equal(status, 400);
    assert.equal(body.code, "invalid_argument");
    assert.match(body.message, /^wi\[0\]: direction has length 2/);
    assert.doesNotMatch(JSON.stringify(body), /\bat .*\.(m?js|ts):\d+/);
  });

  test("a refusal reads as the Connect protocol's, whatever the request's encoding", async () => {
    const response = await fetch(new URL("loomlight.v1.Loomlight/Evaluate", gateway.url), {
      method: "POST", headers: { "content-type": "application/proto" }, body: new Uint8Array(0),
    });
    assert.equal(response.status, 400);
    assert.match(response.headers.get("content-type"), /^application\/json/);
    for (const name of ["grpc-status", "grpc-message"]) assert.equal(response.headers.get(name), null, name);
    const body = await response.json();
    assert.equal(body.code, "invalid_argument");
    assert.match(body.message, /^material/);
    // The same through connect-node's client, binary: the server's code and message, nothing else.
    await assert.rejects(nodeClient(gateway.url).evaluate({ material: { preset: "velvet" }, wi: [0, 0, 2], wo: UP }),
                         (error) => error.code === 3 && /^wi\[0\]: direction has length 2/.test(error.rawMessage));
  });

  test("a streamed Render arrives whole, progress then the image", async () => {
    const updates = [];
    for await (const update of nodeClient(gateway.url).render({
      material: { preset: "velvet" }, sceneName: "sphere", width: 32, height: 32, samplesPerPixel: 2,
    })) updates.push(update);
    const last = updates.at(-1);
    assert.equal(last.width, 32);
    assert.deepEqual([...last.image.subarray(0, 4)], [0x89, 0x50, 0x4e, 0x47]); // PNG
    assert.ok(last.fidelity.length > 0);
  });

  test("a browser that aborts its Render cancels it on the server", async () => {
    const before = await callCount(server, "Render", "CANCELLED");
    const controller = new AbortController();
    const stream = nodeClient(gateway.url).render({
      material: { preset: "velvet" }, sceneName: "drape_stand", width: 512, height: 512, samplesPerPixel: 256,
    }, { signal: controller.signal });
    const iterator = stream[Symbol.asyncIterator]();
    await iterator.next(); // the first progress message: the render runs
    controller.abort();
    await assert.rejects(iterator.next(), /abort|cancel/i);
    await eventually(async () => (await callCount(server, "Render", "CANCELLED")) === before + 1,
                     "the server counts the Render CANCELLED");
  });

  test("a request larger than the server's message limit is refused, and the gateway serves on", async () => {
    const huge = JSON.stringify({ material: { preset: "velvet" }, wi: [], wo: [], pad: "x".repeat(65 << 20) });
    const response = await fetch(new URL("loomlight.v1.Loomlight/Evaluate", gateway.url), {
      method: "POST", headers: { "content-type": "application/json" }, body: huge,
    });
    const body = await response.json();
    assert.equal(body.code, "resource_exhausted");
    assert.ok(body.message.length < 300, "the message does not echo the request");
    const { status } = await connectCall(gateway.url, "ListScenes", {});
    assert.equal(status, 200);
  });

  test("a stalled browser (a half-sent request, an unread stream) holds up neither others nor memory", async () => {
    const { port, hostname } = new URL(gateway.url);
    // A request whose body never comes.
    const loris = netConnect(Number(port), hostname);
    loris.write("POST /loomlight.v1.Loomlight/Evaluate HTTP/1.1\r\nHost: x\r\ncontent-type: application/json\r\n" +
                "content-length: 100000\r\n\r\n{");
    // A 50 MB table streamed to a browser that never reads it.
    const reader = startUnreadTable(gateway.url);
    const cells = async () => {
      const text = await (await fetch(`http://127.0.0.1:${server.metricsPort}/metrics`)).text();
      const line = text.split("\n").find((l) => l.startsWith("loomlight_tabulated_cells_total{"));
      return line ? Number(line.split(" ").pop()) : 0;
    };
    for (let i = 0; i < 5; ++i) {
      const { status, body } = await connectCall(gateway.url, "Evaluate",
        { material: { preset: "velvet" }, wi: UP, wo: UP });
      assert.equal(status, 200);
      assert.equal(body.f.length, 3);
    }
    // Backpressure reaches the server: its table stops growing short of the whole, held by the unread bytes
    // (the server's own bound on unsent bytes, the sockets' buffers, no unbounded buffer in the gateway).
    let previous = -1;
    let current = await cells();
    while (current !== previous || current === 0) {
      await new Promise((resolve) => setTimeout(resolve, 2000));
      [previous, current] = [current, await cells()];
    }
    assert.ok(current < UNREAD_TABLE_CELLS, `${current} of ${UNREAD_TABLE_CELLS} cells computed for a reader that reads nothing`);
    const cancelled = await callCount(server, "Tabulate", "CANCELLED");
    reader.destroy();
    loris.destroy();
    await eventually(async () => (await callCount(server, "Tabulate", "CANCELLED")) === cancelled + 1,
                     "the unread table is cancelled once its browser goes");
  });

  test("only the built page's files are served", async () => {
    for (const path of ["/../package.json", "/%2e%2e/package.json", "/gateway/main.mjs", "/etc/passwd",
                        "/..%2fpackage.json"]) {
      const response = await fetch(new URL(path, gateway.url));
      assert.equal(response.status, 404, path);
    }
  });
});

describe("gateway in front of a TLS server with tokens", () => {
  let server;
  let gateway;
  before(async () => {
    server = await startTlsServer();
    gateway = await startTlsGateway(server);
  });
  after(async () => {
    await gateway?.stop();
    await server?.stop();
  });

  test("the browser's bearer token reaches the server, which decides", async () => {
    const evaluate = { material: { preset: "velvet" }, wi: UP, wo: UP };
    const editor = await connectCall(gateway.url, "Evaluate", evaluate, { authorization: `Bearer ${EDITOR_TOKEN}` });
    assert.equal(editor.status, 200);
    const pipeline = await connectCall(gateway.url, "Evaluate", evaluate,
                                       { authorization: `Bearer ${PIPELINE_TOKEN}` });
    assert.equal(pipeline.body.code, "permission_denied");
    assert.match(pipeline.body.message, /thumbs-pipeline/);
    const nobody = await connectCall(gateway.url, "Evaluate", evaluate);
    assert.equal(nobody.body.code, "unauthenticated");
    const allowed = await connectCall(gateway.url, "ListModels", {}, { authorization: `Bearer ${PIPELINE_TOKEN}` });
    assert.equal(allowed.status, 200);
  });
});
