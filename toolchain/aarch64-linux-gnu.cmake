# Cross toolchain: Debian's g++-aarch64-linux-gnu against a sysroot of Debian's arm64
# packages (toolchain/sysroot-arm64 makes it; `./toolchain/run build aarch64` calls it), and
# qemu-user to run what it builds (the tests, through CTest's emulator support).
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
if(NOT MARKCELL_SYSROOT)
  get_filename_component(MARKCELL_SYSROOT ${CMAKE_CURRENT_LIST_DIR}/../build/sysroot-arm64 ABSOLUTE)
endif()
set(CMAKE_SYSROOT ${MARKCELL_SYSROOT})
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES MARKCELL_SYSROOT)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
# pkg-config reads the sysroot's arm64 .pc files and prefixes what they name with it.
set(ENV{PKG_CONFIG_LIBDIR} ${MARKCELL_SYSROOT}/usr/lib/aarch64-linux-gnu/pkgconfig:${MARKCELL_SYSROOT}/usr/share/pkgconfig)
set(ENV{PKG_CONFIG_SYSROOT_DIR} ${MARKCELL_SYSROOT})
# -L: the dynamic loader and the shared libraries come from the sysroot.
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64-static;-L;${MARKCELL_SYSROOT})
