// The Studio gateway: the browser speaks the Connect protocol (or gRPC-Web) to this process over HTTP/1.1, which
// forwards every call of loomlight.v1.Loomlight and grpc.health.v1.Health unchanged to the C++ server over gRPC
// (HTTP/2), and serves the built page. It adds no policy of its own: the server's checks, limits, fair share and
// errors apply as they are; the bearer token (authorization header) and the deadline pass through, the browser's
// address goes along as X-Forwarded-For (believed by a server started with --trusted-proxy for this host), and a
// browser that goes away cancels its call upstream.
import { readdirSync, readFileSync, statSync } from "node:fs";
import http from "node:http";
import { extname, join, relative, sep } from "node:path";
import { ConnectError, createClient, createContextKey, createContextValues } from "@connectrpc/connect";
import { connectNodeAdapter, createGrpcTransport } from "@connectrpc/connect-node";
import { Health } from "../gen/grpc/health/v1/health_pb.js";
import { Loomlight } from "../gen/loomlight/v1/loomlight_pb.js";

// The server's own bound on one message (server/api/service.h kMaxMessageBytes): a request the server would refuse
// for its size is refused here before it is buffered whole, and a reply the server may send gets through.
export const MAX_MESSAGE_BYTES = 64 << 20;
// Request headers the server reads, passed through; nothing else of the browser's goes upstream.
const PASSED_HEADERS = ["authorization"];
const remoteAddress = createContextKey("");

function upstreamOptions(context) {
  const headers = new Headers();
  for (const name of PASSED_HEADERS) {
    const value = context.requestHeader.get(name);
    if (value !== null) headers.set(name, value);
  }
  const forwarded = context.requestHeader.get("x-forwarded-for");
  const address = context.values.get(remoteAddress);
  if (address) headers.set("x-forwarded-for", forwarded ? `${forwarded}, ${address}` : address);
  return { headers, signal: context.signal, timeoutMs: context.timeoutMs() };
}

// The upstream's error as the browser gets it: its code, message and details, without the upstream's own
// transport headers and trailers (content-type application/grpc, grpc-status, grpc-message), which connect-node
// would otherwise copy into the Connect response and so make the browser's client misread its body.
function downstreamError(error) {
  const upstream = ConnectError.from(error);
  return new ConnectError(upstream.rawMessage, upstream.code, undefined, upstream.details);
}

// One forwarding implementation per method, made from the service's descriptor: a method added to the .proto is
// forwarded without a change here.
function forward(service, client) {
  const implementation = {};
  for (const method of service.methods) {
    const call = client[method.localName];
    switch (method.methodKind) {
      case "unary":
      case "client_streaming":
        implementation[method.localName] = async (input, context) => {
          try {
            return await call(input, upstreamOptions(context));
          } catch (error) {
            throw downstreamError(error);
          }
        };
        break;
      case "server_streaming":
      case "bidi_streaming":
        implementation[method.localName] = async function* (input, context) {
          try {
            yield* call(input, upstreamOptions(context));
          } catch (error) {
            throw downstreamError(error);
          }
        };
        break;
    }
  }
  return implementation;
}

const CONTENT_TYPES = {
  ".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
  ".svg": "image/svg+xml", ".png": "image/png", ".json": "application/json", ".ico": "image/x-icon",
  ".woff2": "font/woff2",
};

// The built page's files, listed once at start: a request names one of them or gets 404, so no URL reaches a path
// outside the build (no "..", no links followed at request time).
function staticFiles(directory) {
  const files = new Map();
  if (!directory) return files;
  const walk = (dir) => {
    for (const name of readdirSync(dir)) {
      const path = join(dir, name);
      const stat = statSync(path);
      if (stat.isDirectory()) walk(path);
      else if (stat.isFile() && CONTENT_TYPES[extname(name)]) {
        files.set("/" + relative(directory, path).split(sep).join("/"), path);
      }
    }
  };
  walk(directory);
  if (files.has("/index.html")) files.set("/", files.get("/index.html"));
  return files;
}

function serveStatic(files) {
  return (request, response) => {
    const path = decodeURIComponent(new URL(request.url, "http://gateway").pathname);
    const file = files.get(path);
    if ((request.method !== "GET" && request.method !== "HEAD") || file === undefined) {
      response.writeHead(404, { "content-type": "text/plain; charset=utf-8" }).end("not found\n");
      return;
    }
    const body = readFileSync(file);
    response.writeHead(200, {
      "content-type": CONTENT_TYPES[extname(file)],
      "content-length": body.length,
      "cache-control": path === "/" || path.endsWith(".html") ? "no-cache" : "max-age=3600",
      "x-content-type-options": "nosniff",
    });
    response.end(request.method === "HEAD" ? undefined : body);
  };
}

/**
 * The gateway's HTTP request handler.
 * upstream: the server's base URL ("http://127.0.0.1:50051", or "https://host:port" with ca for TLS);
 * ca: PEM text of the CA certificates to trust upstream (TLS); serverName: the name its certificate must carry;
 * staticDir: the built page (web/dist), or undefined for the API alone.
 */
export function createGatewayHandler({ upstream, ca, serverName, staticDir }) {
  const nodeOptions = {};
  if (ca) nodeOptions.ca = ca;
  if (serverName) nodeOptions.servername = serverName;
  const transport = createGrpcTransport({
    baseUrl: upstream,
    nodeOptions,
    readMaxBytes: MAX_MESSAGE_BYTES,
    writeMaxBytes: MAX_MESSAGE_BYTES,
    // The server's replies are mostly floats and encoded images: compressing them again costs time, saves little.
    acceptCompression: [],
  });
  const loomlight = createClient(Loomlight, transport);
  const health = createClient(Health, transport);
  return connectNodeAdapter({
    routes(router) {
      router.service(Loomlight, forward(Loomlight, loomlight));
      router.service(Health, forward(Health, health));
    },
    readMaxBytes: MAX_MESSAGE_BYTES,
    writeMaxBytes: MAX_MESSAGE_BYTES,
    acceptCompression: [],
    contextValues: (request) => createContextValues().set(remoteAddress, request.socket.remoteAddress ?? ""),
    fallback: serveStatic(staticFiles(staticDir)),
  });
}

/** An HTTP server running the gateway; listen() it. */
export function createGatewayServer(options) {
  const server = http.createServer(createGatewayHandler(options));
  // A request's headers and body must arrive within these (a slow-loris browser is dropped); a reply may stream for
  // as long as the call runs.
  server.headersTimeout = 20_000;
  server.requestTimeout = 120_000;
  return server;
}
