"""Compensation of the transducer pair (Chapter 5): transfer-function estimation from several
lengths, the calibration file, and frequency-domain filters that compensators apply."""
