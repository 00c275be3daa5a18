"""The statistical BTF model that robot and host share.

The Johnson system (`btf.johnson`), the Slifker-Shapiro percentile solve (`btf.percentile`),
the z ladder and the fixed-point codec with the wire's censor and shift scales (`btf.codec`),
a region's grain and band dependence (`btf.dependence`) and the one fitted-model record
(`btf.record`): what the robot fits, the radio carries and the host stores, samples and
interpolates. It imports numpy and the standard library only, and nothing of this project's
other packages: `btf` <- `radio` <- `onboard` (with `hal`) <- `tools`.
"""
