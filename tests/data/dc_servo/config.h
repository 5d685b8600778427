/* config.h -- state layout of the dcs models (no private memory). */
#ifndef DCS_CONFIG_H
#define DCS_CONFIG_H

enum { S_IA, S_W, S_TH, N_STATES };

#endif /* DCS_CONFIG_H */
