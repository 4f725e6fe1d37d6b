"""Live against refined time, per seed (issue 46, work in progress): cd bench && ../.venv/bin/python refinecompare.py"""
import sys, linemodels
from linemodels import MODELS
from multiprocessing import Pool
def one(job):
    model, seed = job
    s = linemodels.feed(MODELS[model](seed, 120))
    a = linemodels.measure(s); b = linemodels.measure(linemodels.refined_streams(s))
    return model, seed, a.p99, b.p99, a.apart, b.apart
with Pool(2) as p:
    rows = p.map(one, [(m, s) for m in ("gx2sim", "fifo") for s in range(1, 21)])
for m in ("gx2sim", "fifo"):
    r = [x for x in rows if x[0] == m]
    worse = [(x[1], round(x[2],3), round(x[3],3)) for x in r if x[3] > x[2] * 1.05 + 0.01]
    better = sum(x[3] < x[2] - 0.01 for x in r)
    import statistics as st
    print(m, "p99 median live %.3f refined %.3f; apart median live %.3f refined %.3f; better %d, worse %s" % (
        st.median(x[2] for x in r), st.median(x[3] for x in r), st.median(x[4] for x in r), st.median(x[5] for x in r), better, worse))
