from tron1cli.cli.main import main

main()
