import numpy as np, neuralcol, sys
run = neuralcol.pretrained("scape", workers=0); lab = run.labeler
d = np.load(sys.argv[1])
idx = np.flatnonzero(d["pd"] > 0)
rows = []
for k in idx:
    v = d["vertices"][k].astype(np.float64)
    p = lab.penetrations(v, 0.3, seed_vectors=False)
    q = lab.penetrations(v, 1.0, seed_vectors=True)
    reg = int((np.abs(p.vector).sum(1) > 0).sum())
    seeds_only = int(((np.abs(q.vector).sum(1) > 0) & (np.abs(p.vector).sum(1) == 0)).sum())
    rows.append((d["kind"][k], p.n_pairs, reg, seeds_only, d["pd"][k] / lab.diag))
r = np.array(rows)
print("n", len(r), "with enclosed regions", (r[:,2] > 0).sum(), "local only", (r[:,2] == 0).sum())
print("median PD %% diag: regions %.3f, local only %.3f" % (100*np.median(r[r[:,2]>0,4]), 100*np.median(r[r[:,2]==0,4])))
for kd in np.unique(r[:,0]): m = r[:,0]==kd; print("kind", int(kd), "n", m.sum(), "regions", (r[m,2]>0).sum())
