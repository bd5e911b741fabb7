import { useEffect, useRef } from "preact/hooks";
import type { AlignedData } from "uplot";

import { Chart, type ChartSpec } from "../lib/plots";

/** A uPlot chart of fixed data (reports, trends). */
export function StaticChart({ spec, data, name, caption }: { spec: ChartSpec; data: AlignedData; name: string; caption: string }) {
  const ref = useRef<HTMLDivElement>(null);
  const chart = useRef<Chart | null>(null);
  useEffect(() => {
    chart.current = new Chart(ref.current!, spec, data);
    return () => chart.current?.destroy();
  }, [data, spec]);
  return (
    <figure class="plot">
      <figcaption>{caption}</figcaption>
      <div ref={ref} class="plot__canvas" data-plot={name} />
    </figure>
  );
}
