"""The fitter robot and host share: frames and histograms in, Johnson models out.

Feature bands (`features`), ISODATA clustering (`isodata`), the fixed-memory frame fitter
(`fitter`) and its histogram solve (`histogram_fit`, `reads`, `censor`), the bracketing
decision (`bracketing`), a region's grain and band dependence (`dependence`, its anchors in
`anchors`) and a PNG codec (`png`). numpy and the standard library only, so it runs on the
robot as it runs on the host.
"""
