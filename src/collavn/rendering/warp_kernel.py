# mypy: ignore-errors
"""The Warp kernel of :mod:`collavn.rendering.warp_backend`: cast, bodies, shading.

Warp kernels are written in Warp's Python dialect (array annotations are calls,
``wp.tid()`` unpacks), which a static type checker cannot follow; hence the
``ignore-errors`` above, for this file only. The shading is exactly that of
:mod:`collavn.rendering.shading`.
"""

import warp as wp

wp.config.log_level = wp.LOG_WARNING


@wp.func
def _hit_body(o: wp.vec3, d: wp.vec3, cx: float, cy: float, body: wp.vec3) -> wp.vec4:
    """``(t, nx, ny, nz)`` of a ray entering a vertical cylinder; ``t = inf`` on a miss."""
    r, z0, z1 = body[0], body[1], body[2]
    px, py = o[0] - cx, o[1] - cy
    c = px * px + py * py - r * r
    best = wp.float32(wp.inf)
    nx, ny, nz = wp.float32(0.0), wp.float32(0.0), wp.float32(0.0)
    if c <= 0.0 and o[2] >= z0 and o[2] <= z1:
        return wp.vec4(best, nx, ny, nz)
    a = d[0] * d[0] + d[1] * d[1]
    b = px * d[0] + py * d[1]
    disc = b * b - a * c
    if a > 1.0e-12 and disc >= 0.0 and c > 0.0:
        t = (-b - wp.sqrt(disc)) / a
        z = o[2] + t * d[2]
        if t > 0.0 and z >= z0 and z <= z1:
            best = t
            nx = (px + t * d[0]) / r
            ny = (py + t * d[1]) / r
    if d[2] != 0.0 and (o[2] > z1 or o[2] < z0):
        zc = z0
        if o[2] > z1:
            zc = z1
        t = (zc - o[2]) / d[2]
        qx, qy = px + t * d[0], py + t * d[1]
        if t > 0.0 and t < best and qx * qx + qy * qy <= r * r:
            best = t
            nx, ny, nz = 0.0, 0.0, 1.0
    return wp.vec4(best, nx, ny, nz)


@wp.kernel
def render_kernel(mesh: wp.uint64, cam: wp.array(dtype=wp.vec3),
                  views: wp.array2d(dtype=float), bodies: wp.array3d(dtype=float),
                  num_bodies: int, skip: wp.array(dtype=int), body: wp.vec3,
                  face_uv: wp.array2d(dtype=float), face_color: wp.array2d(dtype=float),
                  face_material: wp.array(dtype=int), textures: wp.array4d(dtype=wp.uint8),
                  light: wp.array(dtype=float), palette: wp.array2d(dtype=float),
                  rgb: wp.array3d(dtype=wp.uint8), depth: wp.array2d(dtype=float),
                  ids: wp.array2d(dtype=int)):
    """Pixel ``p`` of view ``b``: the arguments mirror :func:`shading.shade_chunk`."""
    b, p = wp.tid()
    c, s = views[b, 3], views[b, 4]
    e = cam[p]
    d = wp.vec3(c * e[0] - s * e[1], s * e[0] + c * e[1], e[2])
    o = wp.vec3(views[b, 0], views[b, 1], views[b, 2])
    q = wp.mesh_query_ray(mesh, o, d, 1.0e30)
    t = wp.float32(wp.inf)
    if q.result:
        t = q.t
    hit = wp.int32(-1)
    n = wp.vec3(0.0, 0.0, 0.0)
    for a in range(num_bodies):
        if a != skip[b]:
            h = _hit_body(o, d, bodies[b, a, 0], bodies[b, a, 1], body)
            if h[0] < t:
                t = h[0]
                hit = a
                n = wp.vec3(h[1], h[2], h[3])
    if hit >= 0:
        lam = light[0] + light[1] * wp.abs(n[0] * light[2] + n[1] * light[3] + n[2] * light[4])
        j = hit % palette.shape[0]
        for ch in range(3):
            rgb[b, ch, p] = wp.uint8(int(wp.min(palette[j, ch] * lam + 0.5, 255.0)))
        depth[b, p] = t
        ids[b, p] = -2 - hit
    elif q.result:
        f = q.face
        w1, w2 = q.v, 1.0 - q.u - q.v  # Warp's (u, v) weigh corners 0 and 1
        u = face_uv[f, 0] + w1 * face_uv[f, 2] + w2 * face_uv[f, 4]
        v = face_uv[f, 1] + w1 * face_uv[f, 3] + w2 * face_uv[f, 5]
        size = textures.shape[1]
        col = wp.min(int((u - wp.floor(u)) * float(size)), size - 1)
        row = size - 1 - wp.min(int((v - wp.floor(v)) * float(size)), size - 1)
        m = face_material[f]
        for ch in range(3):
            val = float(textures[m, row, col, ch]) * face_color[f, ch] + 0.5
            rgb[b, ch, p] = wp.uint8(int(wp.min(val, 255.0)))
        depth[b, p] = t
        ids[b, p] = f
    else:
        for ch in range(3):
            rgb[b, ch, p] = wp.uint8(0)
        depth[b, p] = 0.0
        ids[b, p] = -1
