import { resolve } from "node:path";
import { defineConfig } from "vite";

// Two pages: the therapist dashboard (index.html, a single-page app) and the patient's
// game overlay (overlay.html). The backend serves dist/ (backend/static.py); in development
// `npm run dev` proxies the API to a running `rehab serve` on port 8000.
export default defineConfig({
  esbuild: { jsx: "automatic", jsxImportSource: "preact" },
  build: {
    target: "es2022",
    sourcemap: false,
    chunkSizeWarningLimit: 200,
    rollupOptions: {
      input: {
        index: resolve(import.meta.dirname, "index.html"),
        overlay: resolve(import.meta.dirname, "overlay.html"),
      },
    },
  },
  server: {
    proxy: {
      "/api": { target: "http://127.0.0.1:8000", ws: true, changeOrigin: false },
    },
  },
});
