import { useState } from "preact/hooks";

import { Alert } from "./bits";
import { api, errorText } from "../lib/api";
import type { Norm, Patient, PatientFields, Side } from "../lib/types";

const DEFAULTS: PatientFields = {
  code: "",
  affected_side: "right",
  upper_arm_length_m: 0.3,
  imu_to_elbow_m: 0.15,
  cuff_to_elbow_m: 0.06,
  tolerance_m: 0.1,
  max_outside_fraction: 0.2,
  displacement_norm: "horizontal",
  warning_after_s: 1,
  notes: "",
};

function CmField({
  label,
  name,
  value,
  onChange,
  min,
  max,
  hint,
}: {
  label: string;
  name: string;
  value: number;
  onChange: (m: number) => void;
  min: number;
  max: number;
  hint?: string;
}) {
  const id = `pf-${name}`;
  return (
    <label class="field" for={id}>
      <span>
        {label} <span class="muted">(cm)</span>
      </span>
      <input
        id={id}
        name={name}
        type="number"
        inputMode="decimal"
        step="0.5"
        min={min}
        max={max}
        required
        value={Math.round(value * 1000) / 10}
        onInput={(e) => onChange(Number(e.currentTarget.value) / 100)}
        aria-describedby={hint ? `${id}-hint` : undefined}
      />
      {hint && (
        <small id={`${id}-hint`} class="muted">
          {hint}
        </small>
      )}
    </label>
  );
}

/** Create (no `patient`) or edit a patient. Codes are pseudonymous: never a name. */
export function PatientForm({ patient, onSaved, onCancel }: { patient?: Patient; onSaved: (p: Patient) => void; onCancel?: () => void }) {
  const [f, setF] = useState<PatientFields>(() => (patient ? { ...DEFAULTS, ...pick(patient) } : { ...DEFAULTS }));
  const [error, setError] = useState<string | null>(null);
  const [busy, setBusy] = useState(false);
  const set = <K extends keyof PatientFields>(k: K, v: PatientFields[K]) => setF((x) => ({ ...x, [k]: v }));
  const adaptive = f.warning_after_s === null;
  // The fixed duration to come back to when "adaptive" is unticked.
  const [lastFixed, setLastFixed] = useState<number>(f.warning_after_s ?? 1);

  const submit = async (ev: Event) => {
    ev.preventDefault();
    setBusy(true);
    setError(null);
    try {
      const saved = patient ? await api.patch<Patient>(`/api/patients/${patient.id}`, f) : await api.post<Patient>("/api/patients", f);
      onSaved(saved);
      if (!patient) setF({ ...DEFAULTS });
    } catch (e) {
      setError(errorText(e));
    } finally {
      setBusy(false);
    }
  };

  return (
    <form class="patient-form" onSubmit={submit} aria-label={patient ? `Edit patient ${patient.code}` : "New patient"}>
      <div class="form-grid">
        <label class="field">
          <span>Pseudonymous code</span>
          <input
            name="code"
            required
            pattern="[A-Za-z0-9_\-]{1,64}"
            title="Letters, digits, - and _ only; never a name"
            value={f.code}
            onInput={(e) => set("code", e.currentTarget.value)}
            aria-describedby="pf-code-hint"
          />
          <small id="pf-code-hint" class="muted">
            e.g. P-014. Never a name.
          </small>
        </label>
        <fieldset class="field">
          <legend>Affected side</legend>
          <div class="radio-row">
            {(["left", "right"] as Side[]).map((s) => (
              <label key={s} class="radio">
                <input type="radio" name="affected_side" value={s} checked={f.affected_side === s} onChange={() => set("affected_side", s)} />
                {s === "left" ? "Left" : "Right"}
              </label>
            ))}
          </div>
        </fieldset>
        <CmField label="Tolerance" name="tolerance" value={f.tolerance_m} min={1} max={50} onChange={(v) => set("tolerance_m", v)} hint="Shoulder movement allowed (paper: 10 cm)" />
        <div class="field">
          <label for="pf-warning">
            Warning after <span class="muted">(s)</span>
          </label>
          <input
            id="pf-warning"
            name="warning_after_s"
            type="number"
            step="0.1"
            min={0}
            max={600}
            required={adaptive === false}
            disabled={adaptive}
            value={adaptive ? "" : (f.warning_after_s ?? lastFixed)}
            onInput={(e) => {
              const v = Number(e.currentTarget.value);
              setLastFixed(v);
              set("warning_after_s", v);
            }}
            aria-describedby="pf-warning-hint"
          />
          <label class="check">
            <input
              type="checkbox"
              name="warning_adaptive"
              checked={adaptive}
              onChange={(e) => set("warning_after_s", e.currentTarget.checked ? null : lastFixed)}
            />
            Adaptive: {Math.round(f.max_outside_fraction * 100)} % of the last cycle
          </label>
          <small id="pf-warning-hint" class="muted">
            Time outside before the orange warning
          </small>
        </div>
        <label class="field">
          <span>
            Compensatory when outside more than <span class="muted">(% of a cycle)</span>
          </span>
          <input
            name="max_outside_fraction"
            type="number"
            step="1"
            min={0}
            max={100}
            required
            value={Math.round(f.max_outside_fraction * 100)}
            onInput={(e) => set("max_outside_fraction", Number(e.currentTarget.value) / 100)}
          />
        </label>
        <label class="field">
          <span>Displacement measured</span>
          <select name="displacement_norm" value={f.displacement_norm} onChange={(e) => set("displacement_norm", e.currentTarget.value as Norm)}>
            <option value="horizontal">In the horizontal plane (top view)</option>
            <option value="3d">In 3D</option>
          </select>
        </label>
        <CmField label="Upper-arm length" name="upper_arm_length" value={f.upper_arm_length_m} min={10} max={60} onChange={(v) => set("upper_arm_length_m", v)} />
        <CmField label="IMU to elbow" name="imu_to_elbow" value={f.imu_to_elbow_m} min={1} max={50} onChange={(v) => set("imu_to_elbow_m", v)} />
        <CmField label="Proximal cuff to elbow" name="cuff_to_elbow" value={f.cuff_to_elbow_m} min={1} max={40} onChange={(v) => set("cuff_to_elbow_m", v)} hint="A property of the robot" />
        <label class="field field--wide">
          <span>Notes</span>
          <textarea name="notes" rows={2} maxLength={10000} value={f.notes} onInput={(e) => set("notes", e.currentTarget.value)} />
          <small class="muted">Clinical notes only: no names or other identifiers.</small>
        </label>
      </div>
      {error && <Alert kind="error">{error}</Alert>}
      <div class="actions">
        <button type="submit" class="btn btn--primary" disabled={busy}>
          {patient ? "Save changes" : "Create patient"}
        </button>
        {onCancel && (
          <button type="button" class="btn btn--ghost" onClick={onCancel}>
            Cancel
          </button>
        )}
      </div>
    </form>
  );
}

function pick(p: Patient): PatientFields {
  const { code, affected_side, upper_arm_length_m, imu_to_elbow_m, cuff_to_elbow_m, tolerance_m, max_outside_fraction, displacement_norm, warning_after_s, notes } = p;
  return { code, affected_side, upper_arm_length_m, imu_to_elbow_m, cuff_to_elbow_m, tolerance_m, max_outside_fraction, displacement_norm, warning_after_s, notes };
}
