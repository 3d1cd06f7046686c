import sys, json, time, numpy as np, neuralcol
from neuralcol.handler.region_push import PushSettings, SmoothField, region_push
run = neuralcol.pretrained("scape", workers=0); lab = run.labeler
d = np.load("/root/neuralcol-cache/collision/6e57e3715ba0952e/realistic_f27405b5550a387c.npz")
idx = np.flatnonzero(d["pd"] > 0)
kw = json.loads(sys.argv[1]); form = sys.argv[2]; n = int(sys.argv[3])
s = PushSettings(**kw, form=form); field = SmoothField(lab.faces, 2161, s.stiffness, s.anchor, form)
res = []
t0 = time.time()
for k in range(n):
    v = d["vertices"][idx[k]].astype(np.float64)
    r = region_push(v, lab, s, field)
    disp = np.linalg.norm(r.vertices - v, axis=1) / lab.diag
    res.append((r.free, disp.max(), np.median(disp), r.iterations))
    if n <= 10: print(k, r.free, "it", r.iterations, "max %.4f med %.5f" % (disp.max(), np.median(disp)), r.pairs[:10])
f = np.array([x[0] for x in res]); mx = np.array([x[1] for x in res]); md = np.array([x[2] for x in res])
print(form, kw, "free %.2f  median disp %.4f%%  p95 max %.2f%%  s/mesh %.2f" % (f.mean(), 100*np.median(md), 100*np.percentile(mx,95), (time.time()-t0)/n))
