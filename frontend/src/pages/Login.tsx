import { useState } from "preact/hooks";

import { api, errorText } from "../lib/api";
import type { Therapist, TokenOut } from "../lib/types";

export function LoginPage({ onLoggedIn }: { onLoggedIn: (me: Therapist) => void }) {
  const [username, setUsername] = useState("");
  const [password, setPassword] = useState("");
  const [error, setError] = useState<string | null>(null);
  const [busy, setBusy] = useState(false);

  const submit = async (ev: Event) => {
    ev.preventDefault();
    setBusy(true);
    setError(null);
    try {
      const out = await api.post<TokenOut>("/api/auth/login", { username, password });
      onLoggedIn(out.therapist);
    } catch (e) {
      setError(errorText(e));
    } finally {
      setBusy(false);
    }
  };

  return (
    <main class="login" id="main">
      <form class="card login__card" onSubmit={submit} aria-labelledby="login-title">
        <h1 id="login-title">Rehab dashboard</h1>
        <p class="muted">Log in to see the devices and your patients.</p>
        <label class="field">
          <span>Username</span>
          <input
            name="username"
            autoComplete="username"
            required
            autoFocus
            value={username}
            onInput={(e) => setUsername(e.currentTarget.value)}
          />
        </label>
        <label class="field">
          <span>Password</span>
          <input
            name="password"
            type="password"
            autoComplete="current-password"
            required
            value={password}
            onInput={(e) => setPassword(e.currentTarget.value)}
          />
        </label>
        {error && (
          <p class="alert alert--error" role="alert">
            {error}
          </p>
        )}
        <button type="submit" class="btn btn--primary btn--wide" disabled={busy}>
          {busy ? "Logging in…" : "Log in"}
        </button>
      </form>
    </main>
  );
}
