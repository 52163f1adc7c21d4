"""Sessions: recording every flight to disk (recorder), and reading any log (.tlog, .bin, .ulg,
.csv, or a recorded session) back into the same sample stream the live link produces, for
replay, what-if, export and reports."""
