// The timing log (#timings): one row per call, round trip measured here and the server's own time.
const MAX_ROWS = 1000; // the log is for a session, not forever: the oldest rows go first

let body: HTMLTableSectionElement;

export function initTimings(table: HTMLTableElement): void {
  table.innerHTML =
    "<thead><tr><th>RPC</th><th>view</th><th>round trip</th><th>server</th><th>result</th></tr></thead><tbody></tbody>";
  body = table.tBodies[0];
}

/** Times `call` and logs it; `serverSeconds` reads total_seconds from the reply where it has one. */
export async function timed<T>(
  rpc: string,
  view: string,
  call: () => Promise<T>,
  serverSeconds: (reply: T) => number | undefined = () => undefined,
): Promise<T> {
  const start = performance.now();
  const row = document.createElement("tr");
  row.dataset.rpc = rpc;
  row.dataset.view = view;
  const cells = [rpc, view, "…", "", "running"].map((text) => {
    const td = document.createElement("td");
    td.textContent = text;
    row.appendChild(td);
    return td;
  });
  body.insertBefore(row, body.firstChild); // newest first: what a designer looks at
  while (body.rows.length > MAX_ROWS) body.deleteRow(body.rows.length - 1);
  try {
    const reply = await call();
    const ms = performance.now() - start;
    cells[2].textContent = `${ms.toFixed(0)} ms`;
    row.dataset.ms = ms.toFixed(1);
    const s = serverSeconds(reply);
    if (s !== undefined) {
      cells[3].textContent = `${(s * 1000).toFixed(1)} ms`;
      row.dataset.serverSeconds = String(s);
    }
    cells[4].textContent = "ok";
    return reply;
  } catch (error) {
    cells[2].textContent = `${(performance.now() - start).toFixed(0)} ms`;
    const aborted = error instanceof Error && /cancel|abort/i.test(error.message);
    cells[4].textContent = aborted ? "aborted" : "error";
    row.classList.add(aborted ? "aborted" : "failed");
    throw error;
  }
}
