// Types of the REST API (backend/schemas) and of the live WebSocket protocol.

import type * as M from "./live-messages";

export type Side = "left" | "right";
export type Norm = "horizontal" | "3d";
export type IndicatorState = "ok" | "outside" | "warning";

export interface Therapist {
  id: number;
  username: string;
  is_admin: boolean;
  active: boolean;
  created_at: string;
}

export interface TokenOut {
  access_token: string;
  token_type: "bearer";
  expires_at: string;
  therapist: Therapist;
}

export interface Params {
  upper_arm_length_m: number;
  imu_to_elbow_m: number;
  cuff_to_elbow_m: number;
  tolerance_m: number;
  max_outside_fraction: number;
  displacement_norm: Norm;
  /** Seconds outside before the warning; null: adaptive (max_outside_fraction × the last cycle). */
  warning_after_s: number | null;
  nominal_shoulder_m: number[] | null;
}

export interface PatientFields {
  code: string;
  affected_side: Side;
  upper_arm_length_m: number;
  imu_to_elbow_m: number;
  cuff_to_elbow_m: number;
  tolerance_m: number;
  max_outside_fraction: number;
  displacement_norm: Norm;
  warning_after_s: number | null;
  notes: string;
}

export interface Patient extends PatientFields {
  id: number;
  created_by_id: number | null;
  created_at: string;
  updated_at: string;
  params: Partial<Params> & Record<string, unknown>;
}

// the pipeline's data-quality counters (live statuses, reports, device stats)
export type Quality = Partial<M.PipelineQuality>;

export interface Device {
  name: string;
  first_seen: string;
  last_seen: string;
  status: "online" | "offline";
  stats: Record<string, unknown> | null;
  active_session_id: number | null;
}

export interface NominalShoulder {
  point: number[];
  source: "params" | "event" | "auto" | "therapist" | "estimate";
  set_at: string;
  set_by: string | null;
}

export type SessionStatus = "active" | "stopped" | "interrupted";

export interface Session {
  id: number;
  patient_id: number;
  patient_code: string;
  device: string;
  therapist: string | null;
  started_at: string;
  stopped_at: string | null;
  status: SessionStatus;
  params: Partial<Params> & Record<string, unknown>;
  recording_path: string | null;
  nominal_shoulder: NominalShoulder | null;
  summary: SessionSummary | null;
}

/** What the sessions table keeps of a finished session's report (GET /api/sessions): enough
 * for a patient's history without fetching reports. */
export interface SessionSummary {
  rows?: number | null;
  cycles?: number | null;
  compensatory_cycles?: number | null;
  compensatory_share?: number | null;
  time_outside_share?: number | null;
  heading_converged_t?: number | null;
  shoulder_displacement_m?: Spread | null;
  elbow_flexion_deg?: Range | null;
  upper_arm_elevation_deg?: Range | null;
  upper_arm_azimuth_deg?: Range | null;
  rejected_messages?: number | null;
  anatomical_rom_deg?: Record<string, Range> | null;
  movement_quality_median?: Partial<Record<QualityField, number | null>> | null;
  [key: string]: unknown;
}

export interface Cycle {
  index: number;
  start: number;
  end: number;
  outside_fraction: number;
  compensatory: boolean;
  coverage?: number | null;
  peak_displacement_m?: number | null;
  max_displacement_m?: number | null;
  recorded_at?: string;
}

export interface OverlayLink {
  path: string;
  token: string;
  expires_at: string;
  device: string;
  session_id: number;
}

export interface Spread {
  median: number | null;
  p95: number | null;
  max: number | null;
}

export interface Range {
  min: number | null;
  max: number | null;
  p5?: number | null;
  p95?: number | null;
  range: number | null;
}

/** The session report (GET /api/sessions/{id}/report); every part optional: older or
 * interrupted sessions may lack some. */
export interface Report {
  device?: string;
  cycles?: Cycle[];
  unjudged_cycles?: Cycle[];
  summary?: {
    rows?: number;
    cycles?: number;
    compensatory_cycles?: number;
    compensatory_share?: number | null;
    time_outside_share?: number | null;
  };
  heading?: { method?: string; first_motion_t?: number | null; converged_t?: number | null };
  upper_arm_length_m?: number;
  upper_arm_length_estimated?: boolean;
  shoulder_displacement_m?: Spread;
  elbow_flexion_deg?: Range;
  upper_arm_elevation_deg?: Range;
  upper_arm_azimuth_deg?: Range;
  cycle_duration_s?: { median: number | null; min: number | null; max: number | null };
  data_quality?: Quality;
  params?: Partial<Params> & Record<string, unknown>;
  anatomical_rom?: AnatomicalRom;
  movement_quality?: MovementQuality;
  key_figures?: KeyFigureOut[];
  /** "wearable": contract §8 (no robot cycles; ``movements`` instead) */
  mode?: "robot" | "wearable";
  movements?: { start: number; end: number }[];
  [key: string]: unknown;
}

/** Shoulder angles (ISB) and elbow flexion per session and per cycle (backend/clinical.py). */
export interface AnatomicalRom {
  reference_frame: string;
  note: string;
  convention: string;
  side: string;
  session: Record<string, Range>;
  cycles: { start: number; end: number; angles: Record<string, Range> }[];
}

export const QUALITY_FIELDS = [
  "movement_time_s",
  "path_length_m",
  "straightness_ratio",
  "mean_speed_m_s",
  "peak_speed_m_s",
  "movement_units",
  "sparc",
  "ldlj",
] as const;
export type QualityField = (typeof QUALITY_FIELDS)[number];

export type QualityCycle = { start: number; end: number; compensatory: boolean | null; path_xy: [number, number][] } & Record<QualityField, number | null>;

/** Movement quality of the wrist cuff's path per cycle, with the session's medians. */
export interface MovementQuality {
  source: string;
  note: string;
  params: Record<string, unknown>;
  cycles: QualityCycle[];
  session_median: Record<QualityField, number | null>;
}

export interface KeyFigureOut {
  key: string;
  label: string;
  value: number | null;
  unit: string;
  detail?: string;
}

/** GET /api/sessions/{id}/report: the report with the session's and patient's metadata. */
export interface ReportOut {
  session?: Record<string, unknown>;
  patient?: { id: number; code: string; affected_side: string };
  provisional?: boolean;
  report: Report;
}

export function unwrapReport(x: ReportOut | Report): Report {
  return x && typeof x === "object" && "report" in x && x.report && typeof x.report === "object"
    ? (x.report as Report)
    : (x as Report);
}

// ---- WebSocket /api/ws/live and /api/ws/overlay --------------------------------------------
// The messages are defined once, in backend/schemas/live.py; live-messages.ts is generated
// from their JSON Schema at build time (npm run types). One client reads either feed, so
// its view of a status or of rows has the overlay's fields and, optionally, the therapists'.

export type { CycleMsg, HelloMsg, StateMsg } from "./live-messages";
export type Num = number | null;
// a robot device's status or a wearable one's (contract §8): what either may carry
type Varying = "quality" | "rates_hz";
export type StatusMsg = M.OverlayStatusMsg &
  Partial<Omit<M.StatusMsg, Varying> & Omit<M.WearableStatusMsg, Varying>> & {
    quality?: Quality & Partial<M.WearableQuality>;
    rates_hz?: Partial<M.Rates>;
  };
export type EstimateRows = Pick<M.LiveRows, "t"> & Partial<M.LiveRows & M.OverlayRows>;
export type RomTest = M.RomTest;
export type JointsMsg = M.JointsMsg;
export interface EstimateMsg {
  type: "estimate";
  device: string;
  rows: EstimateRows;
}
export type LiveMsg = M.HelloMsg | StatusMsg | EstimateMsg | M.StateMsg | M.CycleMsg | JointsMsg;

// each feed's messages are one of the client's
type Accepts<T extends LiveMsg> = T;
export type FeedMsg = Accepts<M.LiveMsg> | Accepts<M.OverlayMsg>;
