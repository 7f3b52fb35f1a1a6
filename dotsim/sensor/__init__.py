"""The IR sensor, in one place: what it is set to (settings: the config's [sensor] table, one scene's
sensor at its render scale, and reading them back from scene.json) and the model that turns rendered
light into the image it sees and says how much noise it adds (model: exposure, bloom, blur, noise,
quantisation, laser speckle, and the random streams it draws from).

The two are modules of their own, and this package imports neither: the settings need only the
standard library (Blender's own Python imports them with the SceneSpec), the model needs scipy.
"""
