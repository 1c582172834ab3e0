"""render: a headless CPU renderer of towns and vehicles with exact labels.

moderngl on Mesa's software rasterizer (llvmpipe) through a headless EGL context;
no GPU, no display. Modules (import them directly; nothing is built on import):

- ``dashtraj.render.gl``: context creation (``create_context``, ``RenderUnavailableError``).
- ``dashtraj.render.meshes``: static town meshes from a ``RoadMap`` and parametric
  vehicle meshes from catalog models.
- ``dashtraj.render.scene``: ``Renderer(road_map, width, height, fov_deg, msaa, look=...)``,
  ``Renderer.render(camera_pose, vehicles) -> Frame`` (rgb, instance, depth, labels),
  ``Renderer.set_look(look)``.
- ``dashtraj.render.look``: ``LookConfig`` (``Weather`` with CARLA's WeatherParameters
  names, ``CameraLook`` with CARLA's camera attribute names, ``Materials``), presets
  (clear, overcast, fog, wet, rain, dusk, flat), ``lighting``.
- ``dashtraj.render.randomize``: ``random_look(rng)`` within the stated ``RANGES``
  (domain randomization of the training sets), ``violations(look)``.
- ``dashtraj.render.shaders``: the GLSL (sun, sky, shadow map, materials, fog, camera
  response); ``dashtraj.render.post``: rain streaks, blur, JPEG after readback.
- ``dashtraj.render.labels``: exact per-vehicle boxes, visibility, truncation and the
  class × orientation label (``DETECTION_CLASSES``).
"""
