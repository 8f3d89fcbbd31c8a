"""The reports' look: the colours (one per kind of trajectory or parameter set, in every
figure) and the page's style sheet, which the calibration report and the fleet report share."""

from __future__ import annotations

#: Reference, datasheet, calibrated, raw G-N, step-1 batches.
REFERENCE, DATASHEET, CALIBRATED, RAW, STEP1 = "#222222", "#d62728", "#1f77b4", "#ff7f0e", "#999999"
#: The lighter shade of the calibrated colour: neighbouring clusters of fitted data alternate.
FITTED_ALT = "#7fb2dc"

#: The style sheet of report.html and of the fleet's report.html.
CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif; margin: 0;
       color: #222; background: #f6f7f9; }
main { max-width: 1100px; margin: 0 auto; padding: 24px; }
h1 { font-size: 1.6em; margin: 0 0 4px 0; } h2 { font-size: 1.2em; margin-top: 28px; }
.meta { color: #666; font-size: 0.9em; }
.verdict { padding: 12px 16px; border-radius: 6px; font-weight: 600; margin: 16px 0; }
.good { background: #e3f4e5; border-left: 6px solid #2e9b3e; }
.partial { background: #fff5dd; border-left: 6px solid #d9a400; }
.bad { background: #fde6e6; border-left: 6px solid #c62828; }
table { border-collapse: collapse; background: white; margin: 8px 0; display: block;
        width: fit-content; max-width: 100%; overflow-x: auto; }
th, td { padding: 6px 12px; border-bottom: 1px solid #e2e4e8; text-align: right; }
td:not(:first-child), .nowrap { white-space: nowrap; }
th { background: #eef0f3; } td:first-child, th:first-child { text-align: left; }
pre { white-space: pre-wrap; overflow-wrap: anywhere; max-width: 100%; }
figure { background: white; margin: 12px 0; padding: 8px; border-radius: 6px; }
figure img { max-width: 100%; height: auto; display: block; }
@media (max-width: 600px) { main { padding: 12px; } th, td { padding: 4px 6px; } }
figcaption { color: #555; font-size: 0.9em; margin-top: 4px; }
ul { line-height: 1.5; } .no { color: #c62828; } .yes { color: #2e9b3e; }
.zero { color: #8a6100; } #corrections td { text-align: left; white-space: normal; }
li.sev-note::marker { color: #888; } li.sev-fallback::marker { color: #d9a400; }
li.sev-fatal::marker { color: #c62828; } .sev-fallback b { color: #8a6100; }
.sev-fatal b { color: #c62828; }
"""
