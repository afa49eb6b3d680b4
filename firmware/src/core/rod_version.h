/* rod_version.h -- the firmware's version: the one place it is defined (sent in HELLO). */
#ifndef ROD_VERSION_H
#define ROD_VERSION_H

#define ROD_FW_VERSION_MAJOR 0
#define ROD_FW_VERSION_MINOR 1
#define ROD_FW_VERSION_PATCH 0

#endif /* ROD_VERSION_H */
