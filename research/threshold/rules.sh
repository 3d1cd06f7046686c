# Sourced by research/threshold/*.sh: the overrides of each registered operating threshold rule
# (docs/studies/operating_threshold.md), for the 2k-vertex presets (RULE_<v>) and anny_body (BODY_<v>).
RULE_v1=(realistic.n_acap_interp=6000 realistic.n_vertex_interp=2400 realistic.n_perturbed=2400
         realistic.per_class=1000 detector.operating_set=realistic_calibration realistic.calibration.scale=1)
BODY_v1=(realistic.n_acap_interp=680 realistic.n_vertex_interp=260 realistic.n_perturbed=260 realistic.per_class=300
         realistic.calibration.per_class=300 detector.operating_set=realistic_calibration realistic.calibration.scale=1)
RULE_v2=(realistic.n_acap_interp=12000 realistic.n_vertex_interp=4800 realistic.n_perturbed=4800
         realistic.per_class=null realistic.calibration.per_class=null realistic.calibration.scale=1
         detector.operating_set=realistic_calibration)
BODY_v2=(realistic.n_acap_interp=1360 realistic.n_vertex_interp=520 realistic.n_perturbed=520 realistic.per_class=null
         realistic.calibration.per_class=null realistic.calibration.scale=1 detector.operating_set=realistic_calibration)
