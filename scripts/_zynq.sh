# shellcheck shell=bash
# The Zynq VM (scripts/zynq-vm, the zynq env of scripts/test); sourced by scripts/_env.sh, not run.
#
# A Zynq-7000 as QEMU models it (`qemu-system-arm -M xilinx-zynq-a9`: one Cortex-A9, 512 MiB, the PS's
# UART, SD controller, Cadence I2C and devcfg), booting Debian 12 armhf with systemd from an emulated SD
# card, as a PYNQ board boots its image. What it is built from, each built once and cached:
#
#   setup_zynq_kernel -> ZYNQ_KERNEL: zImage, stereocam-vm.dtb and modules/ (lib/modules/<version>),
#                        from Debian's linux-source-6.1 with scripts/zynq/kernel.config over
#                        multi_v7_defconfig (every other ARM platform off; see that file for why each
#                        option), cross-compiled with Debian's gcc-arm-linux-gnueabihf
#   setup_zynq_rootfs -> ZYNQ_ROOTFS: the armhf env's rootfs (scripts/_armhf.sh, armhf_rootfs), built
#                        the same way with systemd, udev and kmod besides
#   zynq_image DIR    -> DIR/sd.img: the rootfs, the kernel's modules, this checkout installed into
#                        the PYNQ venv's place and the checks (scripts/zynq/check.py) as a boot service
#   zynq_boot DIR LOG -> boots it; the checks print "ZYNQVM ..." lines on the console, then reboot,
#                        which ends QEMU (-no-reboot)
#
# Cache: $STEREOCAM_ZYNQ_CACHE or ~/.cache/stereocam/zynq-vm, one kernel-<hash> and one rootfs-<hash>,
# each the hash of its inputs (cached_build, scripts/_env.sh). The kernel takes 6-9 minutes of two cores,
# the rootfs about one (its .debs are the armhf env's cache).

ZYNQ_CACHE="${STEREOCAM_ZYNQ_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/stereocam/zynq-vm}"
ZYNQ_KERNEL_SOURCE=/usr/src/linux-source-6.1.tar.xz
# The machine a PYNQ-Z2 is: 512 MiB of DDR (CMA's 128 MiB of it: scripts/zynq/kernel.config).
ZYNQ_MEMORY_MB=512
# systemd as the PYNQ image runs it (Ubuntu's there, Debian 12's 252 here), udev for the device nodes and
# module loading, kmod for modprobe@.service.
ZYNQ_EXTRA_PACKAGES=(systemd systemd-sysv udev kmod)
# The SD card image: QEMU's SD model needs a power of two.
ZYNQ_SD_SIZE=2G

ensure_zynq_tools() {
    local -a missing=()
    command -v qemu-system-arm >/dev/null 2>&1 || missing+=(qemu-system-arm)
    command -v arm-linux-gnueabihf-gcc >/dev/null 2>&1 || missing+=(gcc-arm-linux-gnueabihf)
    [ -f "$ZYNQ_KERNEL_SOURCE" ] || missing+=(linux-source-6.1)
    local tool pkg
    for tool in bc:bc flex:flex bison:bison make:make depmod:kmod mke2fs:e2fsprogs; do
        command -v "${tool%%:*}" >/dev/null 2>&1 || [ -x "/sbin/${tool%%:*}" ] || missing+=("${tool#*:}")
    done
    for pkg in libssl-dev libelf-dev; do
        dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
    done
    if [ "${#missing[@]}" -gt 0 ]; then
        command -v apt-get >/dev/null 2>&1 || die "the Zynq VM needs ${missing[*]} and there is no apt-get: install them"
        apt_install --no-install-recommends "${missing[@]}"
    fi
}

_zynq_kernel_stamp() {
    {
        cat "$ROOT/scripts/zynq/kernel.config" "$ROOT/scripts/zynq/stereocam-vm.dts"
        sed -n '/^# KERNEL BUILD START/,/^# KERNEL BUILD END/p' "${BASH_SOURCE[0]}"
        dpkg-query -W -f '${Version}' linux-source-6.1 2>/dev/null || stat -c %s "$ZYNQ_KERNEL_SOURCE"
    } | sha256sum | cut -c1-16
}

# KERNEL BUILD START (the lines to the END mark are part of the kernel's cache key)
# _zynq_kernel_build OUT LOG: configure and build the kernel, its modules and the device tree into OUT.
_zynq_kernel_build() {
    local out="$1" build_log="$2" src frag start=$SECONDS
    local -a make_args=(ARCH=arm CROSS_COMPILE=arm-linux-gnueabihf- -j"$(nproc)")
    src="$out/src"
    mkdir -p "$src"
    log "zynq: unpacking $(basename "$ZYNQ_KERNEL_SOURCE")"
    tar -xJf "$ZYNQ_KERNEL_SOURCE" -C "$src" --strip-components=1 || die "zynq: cannot unpack $ZYNQ_KERNEL_SOURCE"
    frag="$out/kernel.fragment"
    {
        # Every ARM platform but the Zynq off: their drivers go with them (most of multi_v7's build).
        grep -h -E '^(menu)?config ARCH_[A-Z0-9_]+' "$src"/arch/arm/mach-*/Kconfig | awk '{print $2}' | sort -u \
            | grep -vx -e ARCH_ZYNQ -e ARCH_MULTI_V7 -e ARCH_MULTI_V6 -e ARCH_MULTIPLATFORM \
            | sed 's/^/# CONFIG_/; s/$/ is not set/'
        grep -E '^CONFIG_' "$ROOT/scripts/zynq/kernel.config" | sed -E 's/^(CONFIG_[A-Za-z0-9_]+)=n$/# \1 is not set/'
    } >"$frag"
    log "zynq: configuring the kernel (multi_v7_defconfig + scripts/zynq/kernel.config)"
    (
        cd "$src"
        make "${make_args[@]}" multi_v7_defconfig
        ./scripts/kconfig/merge_config.sh -m .config "$frag"
        make "${make_args[@]}" olddefconfig
        # multi_v7's other modules off: the VM loads only the three the fragment asks for.
        grep '=m$' .config | grep -v -e '^CONFIG_I2C_CHARDEV=' -e '^CONFIG_DRM_VGEM=' -e '^CONFIG_UIO_PDRV_GENIRQ=' \
            -e '^CONFIG_DRM_GEM_SHMEM_HELPER=' | sed -E 's/^(CONFIG_[A-Za-z0-9_]+)=m$/# \1 is not set/' >nomods.fragment
        ./scripts/kconfig/merge_config.sh -m .config nomods.fragment
        make "${make_args[@]}" olddefconfig
    ) >>"$build_log" 2>&1 || { tail -n 20 "$build_log" >&2; die "zynq: kernel configuration failed (log: $build_log)"; }
    local want
    for want in CONFIG_ARCH_ZYNQ=y CONFIG_SERIAL_XILINX_PS_UART_CONSOLE=y CONFIG_MMC_SDHCI_OF_ARASAN=y \
        CONFIG_I2C_CADENCE=y CONFIG_I2C_CHARDEV=m CONFIG_UIO_PDRV_GENIRQ=m CONFIG_DRM_VGEM=m CONFIG_CGROUP_BPF=y \
        CONFIG_FPGA_MGR_ZYNQ_FPGA=y CONFIG_CMA_SIZE_MBYTES=128 CONFIG_SECCOMP_FILTER=y; do
        grep -qx "$want" "$src/.config" || die "zynq: the kernel configuration lacks $want (log: $build_log)"
    done
    cp "$ROOT/scripts/zynq/stereocam-vm.dts" "$src/arch/arm/boot/dts/stereocam-vm.dts"
    log "zynq: building the kernel (about 10 minutes on two cores; log: $build_log)"
    (cd "$src" && make "${make_args[@]}" zImage modules stereocam-vm.dtb \
        && make "${make_args[@]}" INSTALL_MOD_PATH="$out/modules" modules_install) >>"$build_log" 2>&1 \
        || { tail -n 30 "$build_log" >&2; die "zynq: the kernel build failed (log: $build_log)"; }
    cp "$src/arch/arm/boot/zImage" "$src/arch/arm/boot/dts/stereocam-vm.dtb" "$src/.config" "$out/"
    rm -rf "$src" "$out"/modules/lib/modules/*/build "$out"/modules/lib/modules/*/source
    log "zynq: kernel built in $((SECONDS - start))s"
}
# KERNEL BUILD END

# setup_zynq_kernel: the cached kernel for this checkout's configuration; sets ZYNQ_KERNEL.
setup_zynq_kernel() {
    ZYNQ_KERNEL="$ZYNQ_CACHE/kernel-$(_zynq_kernel_stamp)"
    cached_build "$ZYNQ_CACHE/kernel" "$ZYNQ_KERNEL" _zynq_kernel_build
}

# setup_zynq_rootfs: the armhf env's rootfs with systemd, udev and kmod, built once; sets ZYNQ_ROOTFS.
setup_zynq_rootfs() {
    armhf_rootfs "$ZYNQ_CACHE" "${ZYNQ_EXTRA_PACKAGES[@]}"
    ZYNQ_ROOTFS="$ARMHF_BUILT"
    [ -x "$ZYNQ_ROOTFS/lib/systemd/systemd" ] || die "zynq: $ZYNQ_ROOTFS has no systemd: remove it and run again"
}

# setup_zynq: tools, kernel and rootfs. The kernel first: the rootfs waits for the armhf env's lock (the
# armhf env builds its own rootfs under it), and on a fresh machine the kernel's build fills that wait.
setup_zynq() {
    ensure_zynq_tools
    setup_zynq_kernel
    setup_zynq_rootfs
}

# zynq_image DIR: DIR/sd.img, the SD card the VM boots: the cached rootfs (hard links, never written),
# the kernel's modules, this checkout installed as `pip install` would put it in the PYNQ venv, and the
# checks as a service of the boot.
zynq_image() {
    local dir="$1" stage py pyver site venv=/usr/local/share/pynq-venv
    stage="$dir/root"
    rm -rf "$stage"
    # Hard links: the cached rootfs is only read; every file written below is a new one.
    cp -al "$ZYNQ_ROOTFS" "$stage"
    rm -f "$stage/.stereocam-ready"
    cp -a "$ZYNQ_KERNEL/modules/lib/modules" "$stage/lib/"
    pyver="$(basename "$(ls -d "$stage"/usr/lib/python3.[0-9]*/ | grep -E 'python3\.[0-9]+/$' | head -n 1)")"
    site="$stage$venv/lib/$pyver/site-packages"
    mkdir -p "$site" "$stage$venv/bin"
    # The PYNQ image's venv: the system's packages seen through it, stereocam installed in it.
    printf 'home = /usr/bin\ninclude-system-site-packages = true\nversion = %s\n' "${pyver#python}" \
        >"$stage$venv/pyvenv.cfg"
    ln -s /usr/bin/python3 "$stage$venv/bin/python3"
    ln -s python3 "$stage$venv/bin/python"
    (cd "$ROOT" && git ls-files -z stereocam | xargs -0 cp --parents -t "$site")
    py="$(_armhf_host_python)"
    # Byte-compiled here, as pip would at install: the service's file system is read-only (ProtectSystem=).
    "$py" -m compileall -q -j 0 -d "$venv/lib/$pyver/site-packages" "$site/stereocam" >/dev/null
    printf '#!%s/bin/python3\nimport sys\nfrom stereocam.cli import main\nsys.exit(main())\n' "$venv" \
        >"$stage$venv/bin/stereocam"
    chmod 755 "$stage$venv/bin/stereocam"
    # The machine: its id (set, so that systemd does not take the boot for a first boot and apply
    # presets), name, the fabric interrupt's binding as PYNQ's boot arguments make it, no login prompt
    # on the console the checks print on.
    rm -f "$stage/etc/machine-id" "$stage/etc/hostname"
    printf '5c2e0d7a9f3b4e61a8d4c0b7e2f19a63\n' >"$stage/etc/machine-id"
    printf 'pynq\n' >"$stage/etc/hostname"
    mkdir -p "$stage/etc/modprobe.d" "$stage/etc/systemd/system/multi-user.target.wants" "$stage/usr/local/lib/stereocam-vm"
    printf 'options uio_pdrv_genirq of_id=generic-uio\n' >"$stage/etc/modprobe.d/uio.conf"
    ln -sf /dev/null "$stage/etc/systemd/system/serial-getty@ttyPS0.service"
    ln -sf /dev/null "$stage/etc/systemd/system/getty-static.service"
    cp "$ROOT/scripts/zynq/check.py" "$stage/usr/local/lib/stereocam-vm/check.py"
    cat >"$stage/etc/systemd/system/stereocam-vmcheck.service" <<'EOF'
[Unit]
Description=stereocam Zynq VM checks (scripts/zynq-vm)
After=multi-user.target

[Service]
Type=oneshot
ExecStart=/usr/bin/python3 /usr/local/lib/stereocam-vm/check.py
StandardOutput=tty
StandardError=tty
TTYPath=/dev/ttyPS0
Environment=PYTHONUNBUFFERED=1

[Install]
WantedBy=multi-user.target
EOF
    ln -sf ../stereocam-vmcheck.service "$stage/etc/systemd/system/multi-user.target.wants/stereocam-vmcheck.service"
    rm -f "$dir/sd.img"
    mke2fs -q -t ext4 -L rootfs -d "$stage" "$dir/sd.img" "$ZYNQ_SD_SIZE" >/dev/null || die "zynq: mke2fs failed"
    rm -rf "$stage"
}

# zynq_boot DIR LOG TIMEOUT: boot DIR/sd.img; the console goes to LOG. Returns QEMU's status (124: timed out).
zynq_boot() {
    local dir="$1" console_log="$2" limit="$3" rc=0
    timeout --signal=TERM --kill-after=10 "$limit" qemu-system-arm -M xilinx-zynq-a9 -m "$ZYNQ_MEMORY_MB" \
        -kernel "$ZYNQ_KERNEL/zImage" -dtb "$ZYNQ_KERNEL/stereocam-vm.dtb" \
        -drive "if=sd,format=raw,file=$dir/sd.img" \
        -append "console=ttyPS0,115200 root=/dev/mmcblk0 rw rootfstype=ext4 rootwait" \
        -display none -monitor none -serial null -serial "file:$console_log" -no-reboot </dev/null || rc=$?
    return "$rc"
}
