#!/usr/bin/env bash
# Software rendering for every worker on a GPU machine (issue 30, docs/results/costs.md): on the lent 16-core
# machines all workers render through the one GPU's NVIDIA EGL driver, which serialises them (16 processes
# render fewer frames per second than 2). Mesa's llvmpipe renders on the worker's own core instead. The GPU
# image has no Mesa, so its libraries travel as Debian packages, unpacked into a private prefix (nothing on the
# machine is overwritten) and chosen through glvnd's vendor file.
#
#   here, once, from the project root:   bash benchmarks/mesa_egl.sh prepare   # fills .device/mesa (~46 MiB)
#   there (carry .device/mesa):           source benchmarks/mesa_egl.sh use && python benchmarks/render_contention.py ...
#
# `use` unpacks the packages into $BAVO_MESA_PREFIX (default /tmp/bavo-mesa) once, then exports
# __EGL_VENDOR_LIBRARY_FILENAMES (only Mesa's vendor, so glvnd never picks NVIDIA's), LD_LIBRARY_PATH and
# LIBGL_DRIVERS_PATH, plus LP_NUM_THREADS=1 so that each worker's llvmpipe renders on one thread. Checked on the
# 2-core machine with the prefix's libraries (not the system's) mapped into the rendering process
# (`bash benchmarks/mesa_egl.sh check`).
MESA_DEBS=(libegl-mesa0 libgl1-mesa-dri libgbm1 libglapi-mesa libllvm15 libz3-4 libicu72 libxml2 libdrm2 libdrm-common
           libdrm-amdgpu1 libdrm-intel1 libdrm-nouveau2 libdrm-radeon1 libpciaccess0 libwayland-client0
           libwayland-server0 libx11-6 libx11-data libx11-xcb1 libxau6 libxdmcp6 libbsd0 libmd0 libxcb1 libxcb-dri2-0
           libxcb-dri3-0 libxcb-present0 libxcb-randr0 libxcb-sync1 libxcb-xfixes0 libxshmfence1 libsensors5
           libsensors-config libedit2 libelf1)

mesa_prepare() {
    mkdir -p .device/mesa
    grep -qx '/.device/' .git/info/exclude 2>/dev/null || echo '/.device/' >> .git/info/exclude
    (cd .device/mesa && apt-get download "${MESA_DEBS[@]}" >/dev/null) || { echo "apt-get download failed" >&2; return 1; }
    du -sh .device/mesa
}

mesa_use() {
    local prefix=${BAVO_MESA_PREFIX:-/tmp/bavo-mesa} src=${BAVO_MESA_DEBS:-.device/mesa}
    if [ ! -f "$prefix/.done" ]; then
        ls "$src"/*.deb >/dev/null 2>&1 || { echo "mesa_egl: no packages in $src (run 'prepare' and carry it)" >&2; return 1; }
        mkdir -p "$prefix"
        for f in "$src"/*.deb; do dpkg-deb -x "$f" "$prefix" || return 1; done
        touch "$prefix/.done"
    fi
    local lib=$prefix/usr/lib/x86_64-linux-gnu
    printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "%s"}}\n' "$lib/libEGL_mesa.so.0" \
        > "$prefix/mesa_vendor.json"
    export __EGL_VENDOR_LIBRARY_FILENAMES=$prefix/mesa_vendor.json
    export LD_LIBRARY_PATH=$lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
    export LIBGL_DRIVERS_PATH=$lib/dri
    export LP_NUM_THREADS=${LP_NUM_THREADS:-1}
    export MUJOCO_GL=egl
}

mesa_check() {  # render one frame with the prefix's Mesa and show which EGL/GL driver files the process mapped
    BAVO_MESA_PREFIX=${BAVO_MESA_PREFIX:-$(mktemp -d)/mesa} mesa_use || return 1
    python - <<'EOF'
import mujoco, os
from mujoco import gl_context  # noqa: F401  (MUJOCO_GL=egl)
model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>")
with mujoco.Renderer(model, 64, 64) as renderer:
    renderer.update_scene(mujoco.MjData(model))
    frame = renderer.render()
maps = {line.split()[-1] for line in open("/proc/self/maps") if ".so" in line}
names = ("libEGL_mesa", "_dri.so", "libgallium", "libLLVM", "libglapi")
drivers = sorted(p for p in maps if any(n in os.path.basename(p) for n in names))
print("frame", frame.shape, "mean", round(float(frame.mean()), 2))
print("\n".join(drivers))
prefix = os.environ["LIBGL_DRIVERS_PATH"].split("/usr/lib")[0]
assert any("libEGL_mesa" in p for p in drivers) and any("_dri.so" in p for p in drivers), "no Mesa driver mapped"
assert all(p.startswith(prefix) for p in drivers), f"Mesa not loaded from {prefix}"
print("ok: Mesa from", prefix)
EOF
}

case "${1:-}" in
    prepare) mesa_prepare ;;
    use) mesa_use ;;
    check) mesa_check ;;
    *) echo "usage: bash benchmarks/mesa_egl.sh prepare|check, or: source benchmarks/mesa_egl.sh use" >&2
       [ "${BASH_SOURCE[0]}" = "$0" ] && exit 2 ;;
esac
