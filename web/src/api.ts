// The API client: one Connect transport to the gateway (same origin), and how errors read to a designer.
import { createClient, ConnectError, Code } from "@connectrpc/connect";
import { createConnectTransport } from "@connectrpc/connect-web";
import { Loomlight } from "../gen/loomlight/v1/loomlight_pb.js";

// A bearer token for servers that require one (--tokens): kept for this tab only, sent with every call; the gateway
// passes it through to the server, which decides.
const TOKEN_KEY = "loomlight.token";
export const token = (): string => sessionStorage.getItem(TOKEN_KEY) ?? "";
export function setToken(value: string): void {
  if (value) sessionStorage.setItem(TOKEN_KEY, value);
  else sessionStorage.removeItem(TOKEN_KEY);
}

const transport = createConnectTransport({
  baseUrl: window.location.origin,
  useBinaryFormat: true,
  interceptors: [(next) => (request) => {
    const bearer = token();
    if (bearer) request.header.set("authorization", `Bearer ${bearer}`);
    return next(request);
  }],
});
export const client = createClient(Loomlight, transport);

/** True when the call ended because a newer change aborted it (not an error to show). */
export function isAbort(error: unknown): boolean {
  if (error instanceof ConnectError) return error.code === Code.Canceled;
  return error instanceof DOMException && error.name === "AbortError";
}

/** The server is busy (RESOURCE_EXHAUSTED: its or this client's share of long calls or memory in use): retry. */
export function isBusy(error: unknown): boolean {
  return error instanceof ConnectError && error.code === Code.ResourceExhausted;
}

/** The server's message (never a stack), at most 300 characters. */
export function messageOf(error: unknown): string {
  let text: string;
  if (error instanceof ConnectError) {
    text = error.rawMessage || Code[error.code] || "request failed";
    if (error.code === Code.Unavailable)
      text = `server unreachable: ${text}`;
  } else if (error instanceof Error) {
    text = error.message;
  } else {
    text = String(error);
  }
  text = text.split("\n")[0];
  return text.length > 300 ? text.slice(0, 297) + "..." : text;
}

/** The index i of a message naming `material.params[i]`, or -1 (the server names the refused field). */
export function paramIndexOf(error: unknown): number {
  const match = /material\.params\[(\d+)\]/.exec(messageOf(error));
  return match ? Number(match[1]) : -1;
}
