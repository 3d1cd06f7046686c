"""Resolving self-collisions with a :class:`~neuralcol.api.TrainedRun` (docs/handler.md, docs/real_meshes.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from omegaconf import OmegaConf

from neuralcol.api.results import OBJECTIVES, Resolved, check_removed_choice
from neuralcol.errors import UserInputError


class ResolveMixin:
    """:class:`~neuralcol.api.TrainedRun`'s :meth:`resolve` (it uses the run's detector, space and label pool)."""

    def repair_settings(self, repair: bool | None = None):
        """The run's ``handler.repair`` (off for runs older than it) with ``repair`` forcing it on or off."""
        from neuralcol.repair.settings import repair_from_config

        try:
            return repair_from_config(self.cfg, enabled=repair)
        except ValueError as e:
            raise UserInputError(f"{self.run_dir}/.hydra/config.yaml: {e}") from e

    def resolve_sequence(self, frames, rate: float | None = None, progress: bool = True, **resolve_kwargs):
        """Resolve a motion: every frame freed, the corrections varying smoothly in time
        (:mod:`neuralcol.handler.sequence`): each frame is warm-started from the previous frame's correction and
        resolved (:meth:`resolve`, one mesh, with ``resolve_kwargs``) only where that start collides; corrections
        decay where no longer needed and ramp in before a collision, at most ``rate`` per vertex and frame. Free
        frames outside a correction's ramp come back bit for bit (a motion whose frames are all free: unchanged, at
        the cost of one exact verdict a frame); free frames within a ramp move, by design, so the motion stays smooth.

        Args:
            frames: (T, V, 3) the frames in order (T >= 2), numpy or torch.
            rate: the largest change of the correction between frames, as a multiple of the input's own largest
                frame-to-frame vertex move (None: ``handler.sequence.rate``, default 1.0).
            progress: a progress bar over the frames.

        Returns:
            :class:`~neuralcol.handler.sequence.SequenceResolution` (vertices, collides, resolved, correction_jump,
            input_jump, rate, jump_ratio).
        """
        from neuralcol.handler.sequence import frame_jumps, resolve_sequence
        from neuralcol.utils.progress import progress_bar

        v = self._vertices(frames, name="frames").numpy()
        if len(v) < 2:
            raise UserInputError(f"frames: {len(v)} frame; a sequence needs at least 2 (use resolve for one mesh)")
        factor = float(rate if rate is not None else
                       OmegaConf.select(self.cfg, "handler.sequence.rate", default=1.0))
        if not factor > 0:
            raise UserInputError(f"rate={factor}: must be > 0 (a multiple of the input's largest frame-to-frame move)")
        top = float(frame_jumps(v).max())
        step = factor * (top if top > 0 else 1e-3 * self.diagonal)  # a still input: 0.1 % of the diagonal
        self.label_pool()
        lab = self._exact

        def resolve_one(mesh: np.ndarray) -> np.ndarray:
            return self.resolve(mesh[None], **resolve_kwargs).vertices[0].detach().cpu().numpy().astype(np.float64)

        bar = progress_bar(total=len(v), desc="resolving frames", disable=not progress)
        try:
            return resolve_sequence(v, resolve_one, lambda m: bool(lab.verdict(m)), step,
                                    progress=lambda t: bar.update(1))
        finally:
            bar.close()

    def resolve(self, vertices_or_codes, objective: str = "latent", verify: bool = True, margins=None,
                subset=None, anchor: str = "median", repair: bool | None = None, certify: float | None = None, *,
                constraint: str | None = None) -> Resolved:
        """Resolve self-collisions: meshes come back as the user's meshes, corrected; codes as decoded codes.

        The augmented-Lagrangian handler (docs/handler.md) moves each input's latent code to the nearest code
        the detector calls collision-free (the run's ``handler`` settings). For a **mesh**, the correction that
        move implies (the handled code decoded minus the input's own round trip) is added to the input mesh
        (:func:`~neuralcol.stages.handler.transfer_displacement`): the result is in the input's frame and
        keeps its detail, and the exact labeler judges that returned mesh. For a **code**, the result is the
        handled code decoded. With ``verify`` the results the exact labeler still finds self-penetrating are
        handled again with the larger margins (``margins``, default the run's ``handler.verify_margins``) and
        the lowest-PD result is kept; ``verify=False`` trusts the detector (PD after is still measured).

        A **mesh the exact labeler calls free** (PD <= 0; every mesh input is labeled exactly first, with or
        without ``verify``) comes back untouched: ``vertices`` are its own float64 values, bit for bit,
        ``pd_input`` = ``pd_after`` its PD, the displacements 0, ``untouched`` True, ``margin`` NaN, ``repaired``
        False; it goes through neither the encoder nor the handler nor the repair, so ``codes``, ``codes_before``,
        ``decoded`` and ``pd_before`` (the round trip's PD) are NaN for it (``shrink`` / ``cap`` NaN; with
        ``certify`` its verdict is exact and free). A call whose meshes are all free costs one exact label per mesh
        (resolve of one free SCAPE mesh: 13.7 ms, docs/studies/resolve_free_meshes.md). Only the colliding meshes
        are moved.

        Args:
            vertices_or_codes: meshes (N, V, 3) / (V, 3) or codes (N, D) / (D,), numpy or torch.
            objective: ``"latent"`` (stay close to the input's code) or ``"cartesian"`` (stay close to the input
                mesh's vertices; mesh inputs only).
            verify: exact verification with margin escalation.
            margins: verification margins, each above ``handler.alm.margin`` (None: the run's).
            subset: ``objective="cartesian"``: (S,) vertex indices whose positions count (None: all).
            anchor: mesh inputs: ``"median"`` (default) removes the translation the decoder's centroid pinning
                adds to the correction; ``"none"`` keeps the raw difference of the decoded meshes.
            repair: mesh inputs with ``verify``: a returned mesh the exact labeler still finds self-penetrating
                after the margins gets the contact repair (its intersecting triangles pushed apart, our addition;
                docs/real_meshes.md); None: the run's ``handler.repair.enabled``.
            certify: None, or a target FNR: verification through the certified cascade (needs ``verify``;
                docs/cascade.md): a handled result is labeled exactly only where the latent detector's logit on its
                code lies in the run's band for that target (:meth:`band`); below it the detector is trusted (free,
                kept, ``pd_after`` NaN), at or above it the result counts as still colliding (handled again with the
                next margin, then, for meshes, the contact repair). ``exact``, ``free`` and ``exact_share`` of the
                result say which verdicts were exact. The inputs' ``pd_input`` / ``pd_before`` are measured as
                without it.
            constraint: removed with the separate mesh detector (folded into the run's detector; the
                handler's constraint is always the run's detector on the code and, over code and mesh, on its
                decoded geometry): ``constraint="mesh"`` raises a
                UserInputError saying so (``"latent"`` is accepted from old callers).

        Returns:
            :class:`Resolved`.
        """
        from neuralcol.handler.objectives import CartesianObjective, LatentObjective
        from neuralcol.handler.resolve import (
            ANCHORS,
            CertifiedLabel,
            alm_settings,
            certified_outcome,
            detector_logits,
            handle_codes,
            verified_escalation,
        )
        from neuralcol.repair.cap import displacement_stats

        if objective not in OBJECTIVES:
            raise UserInputError(f"objective={objective!r}; use one of {OBJECTIVES}")
        if anchor not in ANCHORS:
            raise UserInputError(f"anchor={anchor!r}; use one of {ANCHORS}")
        check_removed_choice("constraint", constraint, ("mesh",))
        band = None
        if certify is not None:
            if not verify:
                raise UserInputError("certify decides which handled results the exact labeler verifies; it needs "
                                     "verify=True")
            band = self.band(certify)
        x = vertices_or_codes
        v_user = self._vertices(x) if self._is_vertices(x) else None
        z_user = None if v_user is not None else self._codes(x).float().cpu()
        if objective == "cartesian":
            if v_user is None:
                raise UserInputError("objective='cartesian' needs meshes (B, V, 3): their vertices are the targets")
            if subset is not None:
                subset = torch.as_tensor(np.asarray(subset), dtype=torch.long).reshape(-1)
                if len(subset) == 0 or subset.min() < 0 or subset.max() >= self.n_vertices:
                    raise UserInputError(f"subset: vertex indices must lie in [0, {self.n_vertices})")
            target = CartesianObjective(self.space, v_user.float().to(self.device), vertices=subset)
        else:  # (meshes: resolve_meshes' default objective, the same |Z - Z_user|^2 / 2 on the codes it encodes)
            target = None if v_user is not None else LatentObjective(z_user.to(self.device))
        settings = alm_settings(self.cfg.handler.alm)
        margins = [] if not verify else \
            [float(m) for m in (margins if margins is not None else
                                OmegaConf.select(self.cfg, "handler.verify_margins", default=[]))]
        bad = [m for m in margins if m <= settings.margin]
        if bad:
            raise UserInputError(f"margins {bad} must exceed handler.alm.margin = {settings.margin}")
        batch = int(self.cfg.handler.batch_size)
        if v_user is not None:
            return self._resolve_meshes(v_user, target, settings, margins, batch, anchor, verify, repair, band)
        used_margins = np.array([settings.margin, *margins])
        diag = self.diagonal

        def handle(rows: np.ndarray, margin: float):
            idx_map = torch.as_tensor(rows, device=self.device)
            return handle_codes(self.on_codes, z_user[torch.as_tensor(rows)], self.space.box_lo, self.space.box_hi,
                                replace(settings, margin=margin), batch_size=batch,
                                objective=lambda z, idx: target(z, idx_map[idx]))

        def label(z: torch.Tensor, rows=None) -> np.ndarray:
            return self._pd(self.decode(z))

        decide = label if band is None else \
            CertifiedLabel(band, lambda z: detector_logits(self.on_codes, z), label)
        res = handle(np.arange(len(z_user)), settings.margin)
        pd_after = np.full(len(z_user), np.nan)
        pd_after[res.finite.numpy()] = decide(res.z[res.finite])
        z, stage = res.z.float(), np.zeros(len(z_user), dtype=np.int64)
        if margins:
            z, pd_after, stage, _ = verified_escalation(handle, decide, z_user, z, pd_after, margins)
        exact = free = share = None
        if band is not None:
            pd_after, exact, free = certified_outcome(pd_after)
            share = decide.exact_share
        with torch.no_grad():  # (a failed result's code may be non-finite: no input check here)
            verts = self.space.decode(z.to(self.device))
            before = self.space.decode(z_user.to(self.device))
        moved = displacement_stats(before.cpu().numpy(), verts.cpu().numpy(), diag)
        nan = np.full(len(z_user), np.nan)
        return Resolved(vertices=verts, codes=z.to(self.device), codes_before=z_user.to(self.device),
                        pd_input=nan, pd_before=label(z_user), pd_after=pd_after, margin=used_margins[stage],
                        displacement_mean=moved["mean"], displacement_max=moved["max"],
                        displacement_median=moved["median"], diagonal=diag, decoded=verts, exact=exact, free=free,
                        exact_share=share)

    def _resolve_meshes(self, v_user: torch.Tensor, target, settings, margins: list[float], batch: int, anchor: str,
                        verify: bool, repair: bool | None, band) -> Resolved:
        """:meth:`resolve` of meshes (B, V, 3) float64: :func:`~neuralcol.handler.resolve.resolve_meshes`, the free
        inputs returned untouched (exact PD first; no encoder, handler or repair for them)."""
        from neuralcol.handler.resolve import UNTOUCHED, resolve_meshes
        from neuralcol.repair.cap import displacement_stats

        pd_in = self._pd(v_user)
        all_free = len(pd_in) > 0 and bool((pd_in <= 0).all())
        rep = self.repair_settings(repair) if verify and not all_free else None  # (reading it costs ~2 ms)
        if rep is not None:
            self.label_pool()  # the repair asks the run's labeler in this process
        net = None if all_free else self.on_codes  # (the detector over codes costs ~10 ms to build on SCAPE)
        res = resolve_meshes(net, self.space, v_user, self._pd, settings, margins, batch, objective=target,
                             anchor=anchor, pd_input=pd_in, repair=rep,
                             labeler=self._exact if rep is not None else None, certify=band, skip_freed=True)
        untouched = res.stage == UNTOUCHED
        used_margins = np.array([settings.margin, *margins, np.nan])
        margin = np.where(untouched, np.nan, used_margins[np.where(untouched, 0, res.stage)])
        encoded = np.flatnonzero(torch.isfinite(res.codes_before).all(-1).numpy())
        pd_before = np.full(len(v_user), np.nan)
        if len(encoded):
            pd_before[encoded] = self._pd(self.decode(res.codes_before[torch.as_tensor(encoded)]))
        moved = displacement_stats(v_user.numpy(), res.vertices, self.diagonal)
        return Resolved(vertices=torch.as_tensor(res.vertices, dtype=torch.float64, device=self.device),
                        codes=res.codes.to(self.device), codes_before=res.codes_before.to(self.device),
                        pd_input=res.pd_input, pd_before=pd_before, pd_after=res.pd_after, margin=margin,
                        displacement_mean=moved["mean"], displacement_max=moved["max"],
                        displacement_median=moved["median"], diagonal=self.diagonal,
                        decoded=torch.as_tensor(res.decoded, dtype=torch.float32, device=self.device),
                        repaired=res.repaired, exact=res.exact, free=res.free, exact_share=res.exact_share,
                        shrink=res.shrink, cap=res.cap, untouched=untouched)
