"""The table of faceanim's commands: each command's module and its one-line help, so that
``faceanim --help`` lists them all without importing any (a command's module is imported only when
it runs: :func:`faceanim.cli.build_parser`)."""

COMMANDS: dict[str, tuple[str, str]] = {  # name: (module under faceanim.cli, help)
    "demo": ("demo", 'animate the embedded default face: GLB, MP4 and PNGs'),
    "photo": ("photo", "a person's full head from a front photo and side photos: textured, animatable (GLB with "
        '--rig: every control as a morph target)'),
    "track": ("video", "head pose (6 DOF) and the 15 expression control parameters of a video's face, per frame, "
        'as CSV (Chai et al. 2003)'),
    "mocap": ("video", 'motion capture databases from ARKit takes (Chai et al. 2003, section 3)'),
    "perform": ("video", "a video's performance on any face: glTF, MP4 beside the video, or ARKit CSV (Chai et al. "
        '2003)'),
    "arkit": ("video", "Live Link Face recordings (Apple ARKit's 52 curves) played on any face"),
    "live": ("live", 'a camera, a clip or a sound drives ARKit curves live: VMC apps, Unreal Live Link, CSV, the'
        ' viewer'),
    "landmarks": ("mesh", 'detect named 3D landmarks on a mesh'),
    "deform": ("mesh", 'deform a mesh with RBF handles or GDEs from a JSON file'),
    "render": ("mesh", 'render a mesh to PNG'),
    "preprocess": ("mesh", 'crop a scan, resample it on a regular grid, normalise pose and size (also writes '
        'OUT.landmarks.json)'),
    "rig": ("rig", "rig any face mesh: ARKit's 52 blendshapes (Apple's names), visemes, FACS AUs, emotions and"
        ' FAPs as named morph targets (.glb) or a VRM 1.0 or 0.x avatar (.vrm)'),
    "au": ("facs", 'pose a face with FACS action units or an emotion (built-in AU library)'),
    "transfer": ("facs", 'learn AUs from a neutral/expressive scan pair and apply them to a face'),
    "wires": ("wires", 'wire curves: extract from expression templates, apply, edit, blend'),
    "say": ("mpeg4", 'lip-sync: text (synthesized) or recorded speech + transcript to an animated face, on its '
        "ARKit shapes (.glb, .mp4, .csv), as MPEG-4 visemes (.fap) or as Rhubarb Lip Sync's mouth "
        'cues (.tsv, .json); .glb and cues of text also write the sound beside them (.wav)'),
    "fap": ("mpeg4", 'MPEG-4 FAP files'),
    "direct": ("mpeg4", 'render a scene script (YAML or JSON): speech, expressions, head motion, blinks'),
    "view": ("view", 'look at a .glb/.vrm in the browser: sliders for every morph target, play the animation '
        'with its sound, pick landmark/FDP points'),
    "batch": ("batch", 'run one command over a whole dataset on Dask (a local cluster, or --scheduler): every '
        'combination of its inputs, resumable'),
}
HELP = {name: text for name, (_, text) in COMMANDS.items()}
