"""The site assessment report: `aftershock report DIR` over a `run --export` or a `batch` folder.

`gather` reads what the pipeline wrote (summary, poses, map, damage, structure, crack reports, the site index),
`assess` turns it into the report's content (storeys with drift and tilt, crack and debris findings, the ATC-20
detailed-evaluation checklist, a suggested posting), `plan` draws a plan view per storey, and `html` writes one
self-contained HTML file. `report.json` holds the same content: a promise, keys are added, never renamed.
"""
