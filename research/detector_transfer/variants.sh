# Sourced by research/detector_transfer/runs.sh: each variant's overrides (space-separated), for the 2k-vertex
# presets (VARIANTS) and, where it differs, anny_body (BODY_VARIANTS). base: today's defaults.
declare -A VARIANTS BODY_VARIANTS
VARIANTS[base]=""
# rows4: four times the realistic training candidates (drawn as before from the autoencoder's training meshes, seed
# 1), up to four times as many kept per class
VARIANTS[rows4]="detector.geometry.train_set.n_acap_interp=6000 detector.geometry.train_set.n_vertex_interp=2400 detector.geometry.train_set.n_perturbed=2400 detector.geometry.train_set.per_class=2400"
BODY_VARIANTS[rows4]="detector.geometry.train_set.n_acap_interp=1360 detector.geometry.train_set.n_vertex_interp=520 detector.geometry.train_set.n_perturbed=520 detector.geometry.train_set.per_class=600"
# summaries: each sub-domain also reads the summaries of every close pair of the mesh (neuralcol/geometry/contact_summary.py)
VARIANTS[summaries]="detector.geometry.summaries=true"
# summaries_rows4: both
VARIANTS[summaries_rows4]="detector.geometry.summaries=true ${VARIANTS[rows4]}"
BODY_VARIANTS[summaries_rows4]="detector.geometry.summaries=true ${BODY_VARIANTS[rows4]}"
# summaries_smooth_rows4: summaries_rows4 with the continuous form of the summaries (each close pair weighted by how
# close it is; registered after the seed-0 screening of the four above, for the handler's descent)
VARIANTS[summaries_smooth_rows4]="${VARIANTS[summaries_rows4]} detector.geometry.summary_form=smooth"
BODY_VARIANTS[summaries_smooth_rows4]="${BODY_VARIANTS[summaries_rows4]} detector.geometry.summary_form=smooth"
# timing_base / timing_candidate: seed 0 of today's default and of the candidate (summaries_rows4; anny_body with its
# calibration set drawn from 3x the candidates), run alone one after the other with warm caches for criteria (d), (e)
VARIANTS[timing_base]=""
VARIANTS[timing_candidate]="${VARIANTS[summaries_rows4]}"
BODY_VARIANTS[timing_candidate]="${BODY_VARIANTS[summaries_rows4]} realistic.calibration.scale=3"
