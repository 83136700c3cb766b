// The API client: one Connect transport to the gateway (same origin), and how errors read to a designer.
import { createClient, ConnectError, Code } from "@connectrpc/connect";
import { createConnectTransport } from "@connectrpc/connect-web";
import { Loomlight } from "../gen/loomlight/v1/loomlight_pb.js";

const transport = createConnectTransport({ baseUrl: window.location.origin, useBinaryFormat: true });
export const client = createClient(Loomlight, transport);

/** True when the call ended because a newer change aborted it (not an error to show). */
export function isAbort(error: unknown): boolean {
  if (error instanceof ConnectError) return error.code === Code.Canceled;
  return error instanceof DOMException && error.name === "AbortError";
}

/** The server's message (never a stack), at most 300 characters. */
export function messageOf(error: unknown): string {
  let text: string;
  if (error instanceof ConnectError) {
    text = error.rawMessage || Code[error.code] || "request failed";
    // A unary refusal whose body connect-web could not read (the gateway answers it as application/grpc)
    // still carries the server's message in grpc-message: show that rather than "HTTP 400".
    const grpcMessage = error.metadata.get("grpc-message");
    if (/^HTTP \d+$/.test(text) && grpcMessage) text = decodeGrpcMessage(grpcMessage);
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

function decodeGrpcMessage(value: string): string {
  try {
    return decodeURIComponent(value); // gRPC percent-encodes the message
  } catch {
    return value;
  }
}
