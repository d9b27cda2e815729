"""Success of the object relocalisation per parallax bin for MatchConfig variants, on the query maps
kept by `experiments/reloc.py` in runs/reloc/<scene>_seed0.json.

    python studies/reloc_matcher/grid.py hard01,hard02,hard03,hard04,hard05,hard06,hard07 "{}" \
        "{'size_tolerance':0.25,'noise':{'size_rel':0.05},'descriptor':{'label_match':'exact'}}"

K=6 in the environment takes the 6-keyframe queries.
"""
import json, sys, os, itertools, numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[2] / 'experiments'))
import reloc, objslam
from objslam.topo import transform_map_json
scenes = sys.argv[1].split(','); K = int(os.environ.get('K', 3))
data = []
for sc in scenes:
    d = json.load(open(reloc.REPO / 'runs' / 'reloc' / f'{sc}_seed0.json'))
    pj = (reloc.REPO / d['info']['prior_run'] / 'map.json').read_text()
    for q in d['queries']:
        if q['query_keyframes'] != K: continue
        sim = q['similarity']
        data.append((pj, transform_map_json(json.dumps(q['query_map']), sim['yaw'], sim['translation'], sim['scale']),
                     reloc.similarity_matrix(sim['yaw'], sim['translation'], sim['scale']), q['parallax_bin']))
def run(cfg):
    c = {}
    for pj, mq, truth, b in data:
        r = objslam.match_maps(pj, mq, json.dumps(cfg))
        s = reloc._score(np.asarray(r['matrix']) if r['matched'] else None, truth)
        c.setdefault(b, []).append(s['success'])
    return {b: (len(v), round(sum(v)/len(v), 3)) for b, v in sorted(c.items())}, round(np.mean([x for v in c.values() for x in v]), 3)
import ast
for c in sys.argv[2:]:
    cfg = ast.literal_eval(c)
    print(c, *run(cfg), flush=True)
