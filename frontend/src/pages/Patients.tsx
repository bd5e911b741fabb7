import { useEffect, useState } from "preact/hooks";

import { Alert } from "../components/bits";
import { PatientForm } from "../components/PatientForm";
import { api, errorText } from "../lib/api";
import { navigate } from "../lib/router";
import type { Patient } from "../lib/types";

export function PatientsPage() {
  const [patients, setPatients] = useState<Patient[] | null>(null);
  const [query, setQuery] = useState("");
  const [error, setError] = useState<string | null>(null);
  const [creating, setCreating] = useState(false);

  const load = (q: string) =>
    api
      .get<Patient[]>(`/api/patients?limit=1000${q ? `&code=${encodeURIComponent(q)}` : ""}`)
      .then((p) => (setPatients(p), setError(null)))
      .catch((e) => setError(errorText(e)));

  useEffect(() => {
    const t = window.setTimeout(() => load(query), 150);
    return () => window.clearTimeout(t);
  }, [query]);

  return (
    <section class="page" aria-labelledby="patients-title">
      <div class="page__head">
        <h1 id="patients-title">Patients</h1>
        <button type="button" class="btn btn--primary" aria-expanded={creating} onClick={() => setCreating(!creating)}>
          {creating ? "Close" : "New patient"}
        </button>
      </div>
      {creating && (
        <section class="card" aria-labelledby="new-patient-title">
          <h2 id="new-patient-title">New patient</h2>
          <PatientForm
            onSaved={(p) => {
              setCreating(false);
              navigate(`/patients/${p.id}`);
            }}
            onCancel={() => setCreating(false)}
          />
        </section>
      )}
      <label class="field field--inline search">
        <span>Find by code</span>
        <input type="search" value={query} onInput={(e) => setQuery(e.currentTarget.value)} placeholder="e.g. P-01" />
      </label>
      {error && <Alert kind="error">{error}</Alert>}
      {patients === null ? (
        <p role="status">Loading…</p>
      ) : patients.length === 0 ? (
        <p class="empty">{query ? "No patient with that code." : "No patients yet. Create the first one."}</p>
      ) : (
        <div class="table-wrap">
          <table class="table">
            <caption class="sr-only">Patients</caption>
            <thead>
              <tr>
                <th scope="col">Code</th>
                <th scope="col">Affected side</th>
                <th scope="col">Tolerance</th>
                <th scope="col">Warning after</th>
                <th scope="col">Upper arm</th>
                <th scope="col">
                  <span class="sr-only">Actions</span>
                </th>
              </tr>
            </thead>
            <tbody>
              {patients.map((p) => (
                <tr key={p.id}>
                  <th scope="row">
                    <a href={`/patients/${p.id}`}>{p.code}</a>
                  </th>
                  <td>{p.affected_side === "left" ? "Left" : "Right"}</td>
                  <td>{Math.round(p.tolerance_m * 100)} cm</td>
                  <td>{p.warning_after_s === null ? "adaptive" : `${p.warning_after_s} s`}</td>
                  <td>{Math.round(p.upper_arm_length_m * 100)} cm</td>
                  <td>
                    <a href={`/patients/${p.id}`}>History</a>
                  </td>
                </tr>
              ))}
            </tbody>
          </table>
        </div>
      )}
    </section>
  );
}
