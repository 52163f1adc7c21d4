"""Sessions: recordings and the readers that turn logs (.tlog, .csv; later .bin, .ulg) into the
same sample stream the live link produces."""
