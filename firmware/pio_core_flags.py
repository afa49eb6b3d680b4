# PlatformIO post script (platformio.ini: extra_scripts): the portable core must build for the
# Teensy exactly as strictly as on the host. CFLAGS reach C files only, and projenv only the
# project's own sources (not the Teensyduino core), so this makes firmware/src/core C11 with
# warnings as errors while the C++ board code keeps -Wall -Wextra as plain warnings.
Import("projenv")  # noqa: F821 (SCons provides Import)

projenv.Append(CFLAGS=["-std=c11", "-Werror", "-Wdouble-promotion", "-fsingle-precision-constant"])  # noqa: F821
