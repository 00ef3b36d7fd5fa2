"""The damaged-input corpus: generate.py writes it at test time, table.py says what each case must do."""
