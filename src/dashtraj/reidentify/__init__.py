"""Re-identifying the target among the tracks of every observer.

Sits between `dashtraj.reid` (the embedder and gallery) and the experiments:
`decision` turns appearance distances into per-track "target or not" with a
threshold calibrated on training identities; `scoring` measures the accepted
tracks against the truth. The spatio-temporal gate that follows the decision is
`dashtraj.trajectory.gating` (pure road-network math). `rank` orders a sightings
database's tracks by appearance against a query (``dashtraj reid query``; `TrackGallery`
for many queries) and `sheet` draws its contact sheet.
"""
