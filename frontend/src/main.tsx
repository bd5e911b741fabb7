import "uplot/dist/uPlot.min.css";
import "./styles.css";

import { render } from "preact";
import { useEffect, useState } from "preact/hooks";

import { api, hasLoginHint, onUnauthorized, setLoginHint } from "./lib/api";
import { currentPath, match, navigate, onRoute } from "./lib/router";
import type { Therapist } from "./lib/types";
import { DevicesPage } from "./pages/Devices";
import { GridPage } from "./pages/Grid";
import { LivePage } from "./pages/Live";
import { LoginPage } from "./pages/Login";
import { PatientPage } from "./pages/Patient";
import { PatientsPage } from "./pages/Patients";
import { ReportPage } from "./pages/Report";

type Auth = { state: "checking" } | { state: "out" } | { state: "in"; me: Therapist };

function NavLink({ href, label, active }: { href: string; label: string; active: boolean }) {
  return (
    <a href={href} class={active ? "nav__link nav__link--active" : "nav__link"} aria-current={active ? "page" : undefined}>
      {label}
    </a>
  );
}

function App() {
  const [path, setPath] = useState(currentPath());
  const [auth, setAuth] = useState<Auth>({ state: "checking" });

  useEffect(() => onRoute(setPath), []);
  useEffect(() => {
    // Without a remembered login, go straight to the login page (no 401 in the console).
    if (!hasLoginHint()) setAuth({ state: "out" });
    else
      api
        .get<Therapist>("/api/auth/me")
        .then((me) => setAuth({ state: "in", me }))
        .catch(() => {
          setLoginHint(false);
          setAuth({ state: "out" });
        });
    return onUnauthorized(() => {
      setLoginHint(false);
      setAuth({ state: "out" });
    });
  }, []);

  const route = match(path);
  useEffect(() => {
    if (auth.state === "out" && route.name !== "login") {
      const next = currentPath();
      navigate(`/login${next && next !== "/" ? `?next=${encodeURIComponent(next)}` : ""}`, true);
    }
  }, [auth.state, route.name]);

  if (auth.state === "checking") {
    return <p class="loading" role="status">Loading…</p>;
  }
  if (route.name === "login" || auth.state === "out") {
    return (
      <LoginPage
        onLoggedIn={(me) => {
          setLoginHint(true);
          setAuth({ state: "in", me });
          const next = route.query.get("next");
          navigate(next && next.startsWith("/") && !next.startsWith("//") ? next : "/", true);
        }}
      />
    );
  }

  const logout = async () => {
    try {
      await api.post("/api/auth/logout");
    } finally {
      setLoginHint(false);
      setAuth({ state: "out" });
    }
  };

  let page;
  switch (route.name) {
    case "devices":
      page = <DevicesPage />;
      break;
    case "grid":
      page = <GridPage devices={route.query.get("devices")} />;
      break;
    case "live":
      page = <LivePage device={route.params.device!} />;
      break;
    case "patients":
      page = <PatientsPage />;
      break;
    case "patient":
      page = <PatientPage id={Number(route.params.id)} />;
      break;
    case "report":
      page = <ReportPage id={Number(route.params.id)} />;
      break;
    default:
      page = (
        <section class="page">
          <h1>Page not found</h1>
          <p>
            <a href="/">Back to the devices</a>
          </p>
        </section>
      );
  }
  const section = route.name === "live" ? "devices" : route.name === "patient" || route.name === "report" ? "patients" : route.name;
  return (
    <>
      <a class="skip-link" href="#main">
        Skip to content
      </a>
      <header class="topbar">
        <a href="/" class="brand" aria-label="Rehab dashboard, home">
          <svg viewBox="0 0 32 32" width="28" height="28" aria-hidden="true">
            <rect width="32" height="32" rx="7" fill="#0b3d5c" />
            <circle cx="16" cy="16" r="9" fill="none" stroke="#cfd8dc" stroke-width="3" />
            <circle cx="18" cy="14" r="4" fill="#009E73" />
          </svg>
          <span>Rehab</span>
        </a>
        <nav class="nav" aria-label="Main">
          <NavLink href="/" label="Devices" active={section === "devices"} />
          <NavLink href="/patients" label="Patients" active={section === "patients"} />
          <NavLink href="/grid" label="All devices live" active={section === "grid"} />
        </nav>
        <div class="topbar__user">
          <span class="muted">{auth.me.username}</span>
          <button type="button" class="btn btn--ghost" onClick={logout}>
            Log out
          </button>
        </div>
      </header>
      <main id="main" class="main">
        {page}
      </main>
    </>
  );
}

render(<App />, document.getElementById("app")!);
