// loomlight-gateway: serves Loomlight Studio (web/dist) and forwards its Connect calls to a Loomlight server.
//   node gateway/main.mjs [--listen HOST:PORT] [--upstream HOST:PORT] [--upstream-tls-ca FILE]
//                         [--upstream-server-name NAME] [--static DIR]
// Prints "loomlight-gateway: the page is at http://HOST:PORT/" once it listens (port 0: a free one).
import { existsSync, readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { parseArgs } from "node:util";
import { createGatewayServer } from "./gateway.mjs";

const web = join(dirname(fileURLToPath(import.meta.url)), "..");
const usage = `usage: node gateway/main.mjs [--listen HOST:PORT] [--upstream HOST:PORT] [--upstream-tls-ca FILE]
                            [--upstream-server-name NAME] [--static DIR]
  --listen HOST:PORT          where the page and its API are served (default 127.0.0.1:8080; loopback, as the server)
  --upstream HOST:PORT        the Loomlight server (default 127.0.0.1:50051)
  --upstream-tls-ca FILE      reach the server over TLS, trusting the CA certificates in FILE
  --upstream-server-name NAME the name the server's certificate carries (default: the upstream's host)
  --static DIR                the built page (default web/dist)
Browsers' bearer tokens (authorization header) pass through to the server, which needs TLS for them.`;

function fail(message) {
  console.error(`loomlight-gateway: ${message}\n${usage}`);
  process.exit(2);
}

let values;
try {
  ({ values } = parseArgs({
    options: {
      listen: { type: "string", default: "127.0.0.1:8080" },
      upstream: { type: "string", default: "127.0.0.1:50051" },
      "upstream-tls-ca": { type: "string" },
      "upstream-server-name": { type: "string" },
      static: { type: "string", default: join(web, "dist") },
      help: { type: "boolean", short: "h" },
    },
  }));
} catch (error) {
  fail(error.message);
}
if (values.help) {
  console.log(usage);
  process.exit(0);
}
const listen = /^(.*):(\d+)$/.exec(values.listen);
if (!listen) fail(`--listen: '${values.listen.slice(0, 64)}' is not HOST:PORT`);
if (!/^[^/\s]+:\d+$/.test(values.upstream)) fail(`--upstream: '${values.upstream.slice(0, 64)}' is not HOST:PORT`);
let ca;
if (values["upstream-tls-ca"]) {
  try {
    ca = readFileSync(values["upstream-tls-ca"], "utf8");
  } catch (error) {
    fail(`--upstream-tls-ca: ${error.message}`);
  }
}
if (!existsSync(join(values.static, "index.html"))) {
  fail(`--static: no index.html in ${values.static.slice(0, 200)} (build the page: cd web && npm ci && npm run build)`);
}
const server = createGatewayServer({
  upstream: `${ca ? "https" : "http"}://${values.upstream}`,
  ca,
  serverName: values["upstream-server-name"],
  staticDir: values.static,
});
server.on("error", (error) => {
  console.error(`loomlight-gateway: ${error.message}`);
  process.exit(1);
});
server.listen(Number(listen[2]), listen[1].replace(/^\[|\]$/g, ""), () => {
  const { address, port } = server.address();
  const host = address.includes(":") ? `[${address}]` : address;
  console.log(`loomlight-gateway: the page is at http://${host}:${port}/ (server ${values.upstream}` +
              `${ca ? ", TLS" : ""})`);
});
for (const signal of ["SIGINT", "SIGTERM"]) process.on(signal, () => server.close(() => process.exit(0)));
