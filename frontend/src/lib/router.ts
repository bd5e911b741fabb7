// A tiny history-API router: a path signal, `navigate`, and same-origin link interception.

type Listener = (path: string) => void;
const listeners = new Set<Listener>();

export function currentPath(): string {
  return location.pathname + location.search;
}

export function navigate(to: string, replace = false): void {
  if (to === currentPath()) return;
  if (replace) history.replaceState(null, "", to);
  else history.pushState(null, "", to);
  listeners.forEach((fn) => fn(currentPath()));
  if (replace) return; // a redirect: the page's own autofocus (login) keeps the focus
  // Move focus to the new page's heading (screen readers, keyboard users).
  requestAnimationFrame(() => {
    const h = document.querySelector<HTMLElement>("main h1");
    if (h) {
      h.tabIndex = -1;
      h.focus({ preventScroll: false });
    }
  });
}

export function onRoute(fn: Listener): () => void {
  listeners.add(fn);
  return () => listeners.delete(fn);
}

window.addEventListener("popstate", () => listeners.forEach((fn) => fn(currentPath())));

// Internal links (<a href="/..."> without target/download) navigate without a reload.
document.addEventListener("click", (ev) => {
  if (ev.defaultPrevented || ev.button !== 0 || ev.metaKey || ev.ctrlKey || ev.shiftKey) return;
  const a = (ev.target as Element | null)?.closest?.("a");
  if (!a || a.target || a.hasAttribute("download") || a.dataset.external !== undefined) return;
  const href = a.getAttribute("href");
  if (!href || !href.startsWith("/") || href.startsWith("/api/") || href.startsWith("/overlay")) {
    return;
  }
  ev.preventDefault();
  navigate(href);
});

export interface Match {
  name: string;
  params: Record<string, string>;
  query: URLSearchParams;
}

const ROUTES: [string, RegExp][] = [
  ["login", /^\/login$/],
  ["devices", /^\/(?:devices)?$/],
  ["grid", /^\/grid$/],
  ["live", /^\/devices\/(?<device>[A-Za-z0-9_-]{1,64})$/],
  ["patients", /^\/patients$/],
  ["patient", /^\/patients\/(?<id>\d+)$/],
  ["report", /^\/sessions\/(?<id>\d+)$/],
];

export function match(path: string): Match {
  const url = new URL(path, location.origin);
  for (const [name, re] of ROUTES) {
    const m = re.exec(url.pathname);
    if (m) return { name, params: { ...(m.groups ?? {}) }, query: url.searchParams };
  }
  return { name: "notfound", params: {}, query: url.searchParams };
}
