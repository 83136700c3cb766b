// Loomlight Studio: the page (index.html + src/) built into dist/, which the gateway serves next to the API.
import { defineConfig } from "vite";

export default defineConfig({
  root: ".",
  base: "./", // relative URLs: the gateway may serve the page under any path
  build: { outDir: "dist", emptyOutDir: true, target: "es2020" },
});
