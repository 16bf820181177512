"""Long clips as overlapping windows, each its own model, sharing one camera.

A clip longer than one model holds (:func:`~layercam.pipelines.windows.plan.plan`: the analysis's
rule, or ``--window N``) is cut
into overlapping windows of frames. Each window is a run of the ordinary stages (bootstrap,
train, export) in its own folder ``RUN/cache/windows/<first>-<end>/``
(its own stage cache: each window resumes on its own), on its slice of the clip and of the whole
clip's flow, with the model the analysis decided once for the whole clip. The camera is learned
once: window 0 trains as a single model would, and the others start from its tone mapper (and
its learned exposure ratios, ``--exposures alt`` without ``--ev-step``) and hold them fixed, so
that every window renders through the same response curve and exposures (the train stage's key
names window 0's training, :func:`layercam.pipelines.stages.hold_camera`). Window 0 runs first; the
others do not depend on
one another (``--ray``: tasks on a Ray cluster, ``layercam.engine.cluster``).

The windows' outputs are then joined by the ``windows`` stage
(:class:`~layercam.pipelines.windows.join.WindowsStage`): in the
overlap of windows ``k`` and ``k + 1`` (frames ``a_(k+1) .. b_k - 1``) each frame is the
cross-fade ``(1 - w) X_k + w X_(k+1)`` of the linear fade ``f = (t - a_(k+1) + 1) / (overlap + 1)``
weighted per pixel by each window's fit to the overlap's frames (:func:`~layercam.pipelines.windows.plan.overlap_fits`,
:meth:`~layercam.pipelines.windows.plan.Plan.weights`; kept in ``windows/fits.npz`` for ``render`` and ``edit``) of the
linear HDR (``hdr/``), the sharp frames (``frames/``, as floats before they are quantised) and the
foreground's alpha mattes (``alpha/``); the preview is tonemapped once over the joined clip. Each
window's own outputs for ``layercam render`` and ``edit`` (``checkpoint.pt``, ``atlases/``,
``psf.json``) are published under ``windows/w00/``, ... and ``windows.json`` says which frames
each window holds and how they are joined. The top of the run folder stays one set (the blend
stage's folder, published as every run's).

The modules: :mod:`.plan` (where a clip is cut, a window's slice of the clip, the join's weights),
:mod:`.run` (each window's stages, the shared camera), :mod:`.join` (the stage that joins their
outputs) and :mod:`.index` (a published run's ``windows.json``, read by ``render`` and ``edit``).
"""
